"""Voxel grids over a scene's heavy meshes, shared by the shells and the volumetric proxies: where a grid lies,
and the steps of walking the voxels a segment crosses (a 3D-DDA after Amanatides and Woo)."""
import numpy as np
from numba import njit, prange

BOUNDS_CHUNK = 1 << 16  # points per task of `bounds`


def grid_placement(lo, hi, resolution):
    """(corner, voxel size, dimensions) of a grid of `resolution` voxels along the longest side of the box
    [lo, hi], with a free voxel layer all round."""
    pitch = float((hi - lo).max()) / (resolution - 2)
    lo = lo - pitch
    return lo, pitch, np.maximum(np.ceil((hi - lo) / pitch).astype(np.int64) + 2, 3)


def bounds(points):
    """(lo, hi), the corners of the box around `points` (..., 3): one parallel pass (a scene's box is asked for
    at its load and by every render; numpy's six strided reductions took 80 ms for 1.3M triangles)."""
    flat = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if len(flat) == 0:
        raise ValueError("the bounds of no points")
    parts = _chunk_bounds(flat, BOUNDS_CHUNK)
    return parts[:, :3].min(axis=0), parts[:, 3:].max(axis=0)


@njit(cache=True, parallel=True, error_model="numpy")
def _chunk_bounds(flat, chunk):
    """Per chunk of `chunk` rows of `flat` (n, 3), its box: (chunks, 6) of lo and hi, all six NaN where any
    coordinate of the chunk is NaN (numpy's min and max made only that axis NaN; no caller passes NaN)."""
    n = flat.shape[0]
    n_chunks = (n + chunk - 1) // chunk
    out = np.empty((n_chunks, 6))
    for c in prange(n_chunks):
        lo0, lo1, lo2 = flat[c * chunk, 0], flat[c * chunk, 1], flat[c * chunk, 2]
        hi0, hi1, hi2 = lo0, lo1, lo2
        nan = False
        for i in range(c * chunk, min(n, (c + 1) * chunk)):
            x, y, z = flat[i, 0], flat[i, 1], flat[i, 2]
            nan |= (x != x) | (y != y) | (z != z)
            lo0, lo1, lo2 = min(lo0, x), min(lo1, y), min(lo2, z)
            hi0, hi1, hi2 = max(hi0, x), max(hi1, y), max(hi2, z)
        out[c, 0], out[c, 1], out[c, 2], out[c, 3], out[c, 4], out[c, 5] = lo0, lo1, lo2, hi0, hi1, hi2
        if nan:
            out[c, :] = np.nan
    return out


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


@njit(cache=True, error_model="numpy", inline="always")
def walk_start(nx, ny, nz, lo, pitch, ox, oy, oz, dx, dy, dz, tmax):
    """Where the walk of the segment o + t d, t in [0, tmax], through a grid of nx x ny x nz starts: the t range
    (t0, t1) inside the grid (t0 > t1: it misses the grid), then per axis the first voxel, the step, the t of
    the next boundary and the t between boundaries (flat scalars: Numba's parallel analysis takes a tuple of
    three integers for an array shape)."""
    t0, t1 = slab(ox, dx, lo[0], lo[0] + nx * pitch, 0.0, tmax)
    t0, t1 = slab(oy, dy, lo[1], lo[1] + ny * pitch, t0, t1)
    t0, t1 = slab(oz, dz, lo[2], lo[2] + nz * pitch, t0, t1)
    i, si, tx, dtx = axis_start(ox, dx, lo[0], pitch, ox + t0 * dx, nx)
    j, sj, ty, dty = axis_start(oy, dy, lo[1], pitch, oy + t0 * dy, ny)
    k, sk, tz, dtz = axis_start(oz, dz, lo[2], pitch, oz + t0 * dz, nz)
    return t0, t1, i, j, k, si, sj, sk, tx, ty, tz, dtx, dty, dtz


@njit(cache=True, error_model="numpy", inline="always")
def walk_step(i, j, k, si, sj, sk, tx, ty, tz, dtx, dty, dtz, nx, ny, nz):
    """Cross the nearest voxel boundary: the next voxel, the boundaries' new t, and whether it is in the grid."""
    if tx <= ty and tx <= tz:
        return i + si, j, k, tx + dtx, ty, tz, 0 <= i + si < nx
    if ty <= tz:
        return i, j + sj, k, tx, ty + dty, tz, 0 <= j + sj < ny
    return i, j, k + sk, tx, ty, tz + dtz, 0 <= k + sk < nz
