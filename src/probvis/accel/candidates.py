"""Shadow segments tested against a short list of candidate blockers instead of the whole BVH.

The occlusion map and probabilistic visibility both test segments against lists of triangles recorded by
photons. With volumetric culling (`orientation`, see `visibility.occlusion_map.components`), a closed mesh's
triangles that face away from the segment's far end are skipped: a segment that enters the solid must leave
it through a triangle facing its far end, so those alone can be the first blocker found.
"""
import numpy as np
from numba import njit, prange

from .traversal import hit_triangle, ray_setup


@njit(cache=True, error_model="numpy", inline="always")
def culled(orientation, fnormal, t, dx, dy, dz):
    """Volumetric culling: triangle t of a closed component (orientation ±1) faces away from the segment's end."""
    o = orientation[t]
    return o != 0 and o * (fnormal[t, 0] * dx + fnormal[t, 1] * dy + fnormal[t, 2] * dz) <= 0.0


@njit(cache=True, error_model="numpy", inline="always")
def first_blocker(triangles, orientation, fnormal, o, d, rs, tmax, tris, lo, hi):
    """Test candidates tris[lo:hi] in order until one blocks the segment o + t d, t in (0, tmax); `rs` is
    `ray_setup(d)`. Returns (blocked, triangle tests, culled candidates)."""
    kx, ky, kz, sx, sy, sz = rs
    n_tri, n_cull = 0, 0
    for c in range(lo, hi):
        t = tris[c]
        if culled(orientation, fnormal, t, d[0], d[1], d[2]):
            n_cull += 1
            continue
        n_tri += 1
        if hit_triangle(triangles, t, o, kx, ky, kz, sx, sy, sz, 0.0, tmax)[0] < np.inf:
            return True, n_tri, n_cull
    return False, n_tri, n_cull


@njit(cache=True, parallel=True, error_model="numpy")
def visibility_from_lists(triangles, orientation, fnormal, org, dirs, tmax, lo, hi, tris):
    """Binary visibility of each segment against its own candidate list tris[lo[s]:hi[s]]: (visibility,
    triangle tests, culled candidates) per segment."""
    n = org.shape[0]
    vis = np.ones(n)
    n_tri = np.zeros(n, np.int32)
    n_cull = np.zeros(n, np.int32)
    for s in prange(n):
        o = (org[s, 0], org[s, 1], org[s, 2])
        d = (dirs[s, 0], dirs[s, 1], dirs[s, 2])
        blocked, a, b = first_blocker(triangles, orientation, fnormal, o, d, ray_setup(d[0], d[1], d[2]), tmax[s],
                                      tris, lo[s], hi[s])
        if blocked:
            vis[s] = 0.0
        n_tri[s], n_cull[s] = a, b
    return vis, n_tri, n_cull
