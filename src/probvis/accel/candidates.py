"""Shadow segments tested against a short list of candidate blockers instead of the whole BVH.

The occlusion map and probabilistic visibility both test segments against lists of triangles recorded by
photons. With volumetric culling (`orientation`, see `visibility.occlusion_map.components`), a closed mesh's
triangles that face away from the segment's far end are skipped: a segment that enters the solid must leave
it through a triangle facing its far end, so those alone can be the first blocker found.
"""
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from .traversal import ray_setup, sheared_blocks, triangle_blocks

GATHER = 16  # candidates gathered into contiguous memory at a time by `buffered_blocker`


class CandidateGeometry(NamedTuple):
    """The scene as the candidate-list test takes it."""

    triangles: np.ndarray  # (n, 3, 3)
    orientation: np.ndarray  # (n,) int8: +1 or -1 for a closed component's triangles (volumetric culling), else 0
    fnormal: np.ndarray  # (n, 3) unit face normals


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
        if triangle_blocks(triangles, t, o, kx, ky, kz, sx, sy, sz, 0.0, tmax):
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


@njit(cache=True, error_model="numpy", inline="always")
def buffered_blocker(cand, tris, lo, hi, buf, cull, row0, have, ox, oy, oz, o, d, shear, tmax):
    """`first_blocker` of one segment (origin o, direction d, `ray_setup` shear, t in (0, tmax)) over candidates
    tris[lo:hi], read from contiguous rows of `buf` (the vertices minus the buffer's origin (ox, oy, oz)) and
    `cull` (orientation, face normal): candidate lo + r is row row0 + r. The rows are gathered as the segment
    first needs them, GATHER at a time; `have` says how many of the range's rows are there. The segments of one
    shading point towards one emitter share the buffer (and their origin), so each candidate is gathered once
    for all of them; a segment whose origin differs tests the scene's triangles as `first_blocker` does.
    Returns (blocked, triangle tests, culled candidates, rows now gathered)."""
    if not (o[0] == ox and o[1] == oy and o[2] == oz):
        blocked, tests, culls = _unbuffered(cand, o, d, shear, tmax, tris, lo, hi)
        return blocked, tests, culls, have
    kx, ky, kz, sx, sy, sz = shear
    tests, culls = 0, 0
    for r in range(hi - lo):
        if r >= have:
            have = _gather(cand, tris, lo, buf, cull, row0, have, min(hi - lo, have + GATHER), ox, oy, oz)
        w = row0 + r
        c = cull[w, 0]
        if c != 0.0 and c * (cull[w, 1] * d[0] + cull[w, 2] * d[1] + cull[w, 3] * d[2]) <= 0.0:
            culls += 1
            continue
        tests += 1
        if sheared_blocks(buf[w, kx], buf[w, ky], buf[w, kz], buf[w, 3 + kx], buf[w, 3 + ky], buf[w, 3 + kz],
                          buf[w, 6 + kx], buf[w, 6 + ky], buf[w, 6 + kz], sx, sy, sz, 0.0, tmax):
            return True, tests, culls, have
    return False, tests, culls, have


@njit(cache=True, error_model="numpy")
def _unbuffered(cand, o, d, shear, tmax, tris, lo, hi):
    """`first_blocker` of a segment that does not share the buffer's origin. Out of line: inlined, its reads of
    the candidate geometry cost every segment reference counting, taken or not."""
    return first_blocker(cand.triangles, cand.orientation, cand.fnormal, o, d, shear, tmax, tris, lo, hi)


@njit(cache=True, error_model="numpy")
def _gather(cand, tris, lo, buf, cull, row0, have, end, ox, oy, oz):
    """Rows have..end-1 of the range at lo (buffer rows row0 + ...): vertices minus (ox, oy, oz), orientation and
    face normal of candidates tris[lo + have:lo + end]; returns end. Out of line: it runs once per GATHER
    candidates for all the segments that share the rows."""
    tv = cand.triangles
    for g in range(have, end):
        t = tris[lo + g]
        w = row0 + g
        for v in range(3):
            buf[w, 3 * v] = tv[t, v, 0] - ox
            buf[w, 3 * v + 1] = tv[t, v, 1] - oy
            buf[w, 3 * v + 2] = tv[t, v, 2] - oz
        cull[w, 0] = cand.orientation[t]
        cull[w, 1], cull[w, 2], cull[w, 3] = cand.fnormal[t, 0], cand.fnormal[t, 1], cand.fnormal[t, 2]
    return end
