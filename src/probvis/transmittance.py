"""Volumetric proxies: heavy meshes made of many small disconnected parts (foliage) prefiltered into a voxel grid
of extinction, and the transmittance exp(-∫σ) of a segment through it (after the aggregate, volumetric
level-of-detail representations of foliage, e.g. Loubet and Neyret, "Hybrid mesh-volume LoDs", 2017).

Quadric decimation keeps a mesh's surface by collapsing its edges; a million separate leaves have no edges to
collapse, so a decimated canopy disagrees with the real one on most segments. What a coarse model can keep of
such geometry is its density: a segment through a cloud of small, randomly oriented flat parts is blocked
with probability about 1 - exp(-∫σ ds), σ the parts' projected area per volume (a flat part of area A shows
A / 2 on average over all directions). The grid has `resolution` voxels along the longest side of the meshes'
bounds; every triangle adds A / 2 to the voxel holding its centroid. Any value in [0, 1] is a valid control
variate for the proxy estimator; this one is merely close to V's expectation, so that the correction, and its
variance, are small where the foliage is sparse or dense.
"""
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from .voxels import bounds, grid_placement, walk_start, walk_step

RESOLUTION = 64  # voxels along the longest side of the prefiltered meshes' bounds
SMALL_PARTS = 1.5  # a mesh whose welded vertices exceed this many per triangle is mostly separate small parts


class VolumeArrays(NamedTuple):
    """An `ExtinctionGrid` as the kernels take it."""

    sigma: np.ndarray  # (X, Y, Z) float64 projected area per volume
    lo: np.ndarray  # (3,) the grid's corner
    pitch: float


@dataclass
class ExtinctionGrid:
    """σ (projected area per volume) per voxel of the prefiltered meshes, and the grid's placement."""

    sigma: np.ndarray  # (X, Y, Z) float64
    lo: np.ndarray  # (3,) the grid's corner
    pitch: float

    @property
    def arrays(self):
        return VolumeArrays(self.sigma, self.lo, self.pitch)

    @property
    def nbytes(self):
        return self.sigma.nbytes

    @classmethod
    def none(cls):
        """No volumetric proxy: a single empty voxel far away, which no segment reaches."""
        return cls(np.zeros((1, 1, 1)), np.full(3, 1e30), 1.0)


def mostly_small_parts(n_vertices, n_triangles):
    """Whether a welded mesh of `n_vertices` for `n_triangles` is mostly separate small parts (a closed or
    connected surface has about half a vertex per triangle, separate triangles three)."""
    return n_vertices > SMALL_PARTS * n_triangles


def extinction_grid(parts, resolution=RESOLUTION):
    """The `ExtinctionGrid` of triangle soups `parts` (a list of (n, 3, 3) arrays)."""
    lo = np.min([bounds(t)[0] for t in parts], axis=0)
    hi = np.max([bounds(t)[1] for t in parts], axis=0)
    lo, pitch, dims = grid_placement(lo, hi, resolution)
    sigma = np.zeros(int(np.prod(dims)))
    for tris in parts:
        _deposit(tris, lo, pitch, dims[0], dims[1], dims[2], sigma)
    return ExtinctionGrid(sigma.reshape(dims) / pitch ** 3, lo, pitch)


@njit(cache=True, error_model="numpy")
def _deposit(tris, lo, pitch, nx, ny, nz, sigma):
    """Add half of each triangle's area to the flat voxel of `sigma` that holds its centroid, in triangle order
    (one pass; numpy's temporaries took 0.2 s for a million triangles)."""
    for t in range(tris.shape[0]):
        ax, ay, az = tris[t, 1, 0] - tris[t, 0, 0], tris[t, 1, 1] - tris[t, 0, 1], tris[t, 1, 2] - tris[t, 0, 2]
        bx, by, bz = tris[t, 2, 0] - tris[t, 0, 0], tris[t, 2, 1] - tris[t, 0, 1], tris[t, 2, 2] - tris[t, 0, 2]
        cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        area = 0.5 * np.sqrt(cx * cx + cy * cy + cz * cz)
        cell = 0
        for a, n in ((0, nx), (1, ny), (2, nz)):
            c = (tris[t, 0, a] + tris[t, 1, a] + tris[t, 2, a]) / 3.0
            cell = cell * n + min(max(np.int64(np.floor((c - lo[a]) / pitch)), 0), n - 1)
        sigma[cell] += 0.5 * area


@njit(cache=True, error_model="numpy", inline="always")
def optical_depth(volume, ox, oy, oz, dx, dy, dz, tmax):
    """∫σ ds along the segment o + t d, t in [0, tmax], through the `VolumeArrays`, walking the voxels it crosses
    (3D-DDA), and the voxels visited."""
    sigma = volume.sigma
    nx, ny, nz = sigma.shape
    t0, t1, i, j, k, si, sj, sk, tx, ty, tz, dtx, dty, dtz = walk_start(nx, ny, nz, volume.lo, volume.pitch, ox, oy,
                                                                        oz, dx, dy, dz, tmax)
    if t0 > t1:
        return 0.0, 0
    tau, steps, t_in = 0.0, 0, t0
    inside = True
    while inside:
        steps += 1
        t_out = min(tx, ty, tz)
        tau += sigma[i, j, k] * (min(t_out, t1) - t_in)
        if t_out >= t1:
            break
        t_in = t_out
        i, j, k, tx, ty, tz, inside = walk_step(i, j, k, si, sj, sk, tx, ty, tz, dtx, dty, dtz, nx, ny, nz)
    return tau * math.sqrt(dx * dx + dy * dy + dz * dz), steps


@njit(cache=True, parallel=True, error_model="numpy")
def transmittances(volume, org, dirs, tmax):
    """exp(-∫σ ds) of each segment o + t d, t in [0, tmax], through the `VolumeArrays`, and the voxels each walk
    visited."""
    n = len(org)
    out, steps = np.empty(n), np.empty(n, np.int32)
    for s in prange(n):
        tau, steps[s] = optical_depth(volume, org[s, 0], org[s, 1], org[s, 2], dirs[s, 0], dirs[s, 1],
                                      dirs[s, 2], tmax[s])
        out[s] = math.exp(-tau)
    return out, steps
