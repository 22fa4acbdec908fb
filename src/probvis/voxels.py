"""Voxel grids over a scene's heavy meshes, shared by the shells and the volumetric proxies: where a grid lies,
and the steps of walking the voxels a segment crosses (a 3D-DDA after Amanatides and Woo)."""
import numpy as np
from numba import njit


def grid_placement(lo, hi, resolution):
    """(corner, voxel size, dimensions) of a grid of `resolution` voxels along the longest side of the box
    [lo, hi], with a free voxel layer all round."""
    pitch = float((hi - lo).max()) / (resolution - 2)
    lo = lo - pitch
    return lo, pitch, np.maximum(np.ceil((hi - lo) / pitch).astype(np.int64) + 2, 3)


@njit(cache=True, error_model="numpy", inline="always")
def slab(o, d, lo, hi, t0, t1):
    """The interval [t0, t1] narrowed to where o + t d lies in [lo, hi] (empty: t0 > t1)."""
    if d != 0.0:
        ta, tb = (lo - o) / d, (hi - o) / d
        return max(t0, min(ta, tb)), min(t1, max(ta, tb))
    if o < lo or o > hi:
        return 1.0, 0.0
    return t0, t1


@njit(cache=True, error_model="numpy", inline="always")
def axis_start(o, d, lo, pitch, p, n):
    """Along one axis: the voxel holding coordinate p (clamped into the grid), the step, the t of the next
    voxel boundary and the t between boundaries, for the segment o + t d."""
    i = min(n - 1, max(0, np.int64(np.floor((p - lo) / pitch))))
    if d > 0.0:
        return i, 1, (lo + (i + 1) * pitch - o) / d, pitch / d
    if d < 0.0:
        return i, -1, (lo + i * pitch - o) / d, -pitch / d
    return i, 0, np.inf, np.inf
