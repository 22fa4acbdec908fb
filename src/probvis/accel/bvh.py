"""Bounding volume hierarchy over triangles, built top-down with the binned surface-area heuristic.

Layout (depth-first): the left child of interior node i is i + 1; `node_index[i]` is the right child of an
interior node or the first primitive of a leaf; `node_count[i]` is 0 for interior nodes and the number of
primitives of a leaf.
Triangle vertices are stored in BVH order in `tri_v`; `prim_ids` maps BVH order back to scene triangle ids.
"""
import time
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from .sah_build import MAX_LEAF, N_BINS, TRAVERSAL_COST, node_arrays, surface_area


@njit(cache=True, parallel=True, error_model="numpy")
def _primitive_bounds(tris, lo, hi, cent, idx):
    """Each triangle's bounds, their centre and its id, on every thread (the pages first touched in parallel)."""
    for i in prange(tris.shape[0]):
        idx[i] = i
        for k in range(3):
            a, b, c = tris[i, 0, k], tris[i, 1, k], tris[i, 2, k]
            lo[i, k] = min(min(a, b), c)
            hi[i, k] = max(max(a, b), c)
            cent[i, k] = 0.5 * (lo[i, k] + hi[i, k])


@njit(cache=True, parallel=True, error_model="numpy")
def _gather(tris, idx, out):
    """out[i] = tris[idx[i]]: the triangles in BVH order."""
    for i in prange(idx.shape[0]):
        for v in range(3):
            for k in range(3):
                out[i, v, k] = tris[idx[i], v, k]

@njit(cache=True, error_model="numpy")
def _depth_stats(node_index, node_count):
    n = node_index.shape[0]
    depth = np.zeros(n, np.int32)
    max_depth = 0
    for i in range(n):
        if node_count[i] == 0 and i + 1 < n:
            depth[i + 1] = depth[i] + 1
            depth[node_index[i]] = depth[i] + 1
        max_depth = max(max_depth, depth[i])
    return max_depth


@njit(cache=True, error_model="numpy")
def _tree_sums(bounds, node_count):
    """For `BVH.stats`, in one pass over the nodes: the number of leaves, the surface area of the interior nodes
    and the leaves' area times their primitive count."""
    n_leaves, inner, leaf = 0, 0.0, 0.0
    for i in range(bounds.shape[0]):
        dx, dy, dz = bounds[i, 3] - bounds[i, 0], bounds[i, 4] - bounds[i, 1], bounds[i, 5] - bounds[i, 2]
        area = 2.0 * (dx * dy + dy * dz + dz * dx)
        if node_count[i] == 0:
            inner += area
        else:
            n_leaves += 1
            leaf += area * node_count[i]
    return n_leaves, inner, leaf


class BVHArrays(NamedTuple):
    """What the traversal kernels take: float and int64 views of the same node records (see `_pack`), the root
    box as a (1, 6) array, triangle vertices and scene triangle ids in BVH order, and the stack depth needed."""

    records: np.ndarray
    ints: np.ndarray
    root: np.ndarray
    tri_v: np.ndarray
    prim_ids: np.ndarray
    stack_depth: int


@dataclass
class BVH:
    bounds: np.ndarray
    node_index: np.ndarray
    node_count: np.ndarray
    tri_v: np.ndarray  # (n, 3, 3) vertices in BVH order
    prim_ids: np.ndarray  # BVH order -> scene triangle id
    max_depth: int
    build_seconds: float

    packed: np.ndarray = None  # (n, 16) float64 traversal records, see `_pack`

    def __post_init__(self):
        self.packed = _pack(self.bounds, self.node_index, self.node_count)

    @property
    def nbytes(self):
        """Bytes held: node arrays, their packed traversal records and the triangles in BVH order."""
        return sum(a.nbytes for a in (self.bounds, self.node_index, self.node_count, self.tri_v, self.prim_ids,
                                      self.packed))

    @property
    def arrays(self):
        """The `BVHArrays` handed to the traversal kernels."""
        return BVHArrays(self.packed, self.packed.view(np.int64), self.bounds[:1].copy(), self.tri_v, self.prim_ids,
                         self.max_depth + 2)

    def stats(self):
        n_leaves, inner_area, leaf_cost = _tree_sums(self.bounds, self.node_count)
        return {
            "nodes": int(len(self.node_count)),
            "leaves": n_leaves,
            "max_depth": self.max_depth,
            "mean_leaf_size": len(self.prim_ids) / n_leaves,
            "max_leaf_size": int(self.node_count.max()),
            "sah_cost": (TRAVERSAL_COST * inner_area + leaf_cost) / float(surface_area(self.bounds[0])),
            "build_seconds": self.build_seconds,
            "bytes": self.nbytes,
        }


@njit(cache=True, parallel=True, error_model="numpy")
def _fill_records(rec, ints, bounds, node_index, node_count):
    for i in prange(bounds.shape[0]):
        inner = node_count[i] == 0
        for k in range(6):
            rec[i, k] = bounds[i + 1, k] if inner else 0.0
            rec[i, 6 + k] = bounds[node_index[i], k] if inner else 0.0
        ints[i, 12] = node_index[i]
        ints[i, 13] = node_count[i]
        ints[i, 14] = 0
        ints[i, 15] = 0


def _pack(bounds, node_index, node_count):
    """Two cache lines per node: both children's boxes in float64 (columns 0-11, so one visit tests the two
    children with the exact bounds), then as int64 the right child or first primitive (12) and the leaf
    primitive count (13, 0 for interior nodes)."""
    buf = np.empty(len(bounds) * 16 + 8, np.float64)
    start = (-buf.ctypes.data % 64) // 8  # align records to 64 bytes
    rec = buf[start:start + len(bounds) * 16].reshape(-1, 16)
    _fill_records(rec, rec.view(np.int64), bounds, node_index, node_count)
    return rec

def build_bvh(triangles, n_bins=N_BINS, max_leaf=MAX_LEAF):
    """Build a BVH over `triangles` (n, 3, 3) float64. Large meshes build on all threads; the tree is the same
    as a single-threaded build's."""
    tris = np.ascontiguousarray(triangles, dtype=np.float64)
    t0 = time.perf_counter()
    n = len(tris)
    lo, hi, cent, idx = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty(n, np.int32)
    _primitive_bounds(tris, lo, hi, cent, idx)
    bounds, node_index, node_count = node_arrays(lo, hi, cent, idx, n_bins, max_leaf)
    tri_v = np.empty_like(tris)
    _gather(tris, idx, tri_v)
    depth = int(_depth_stats(node_index, node_count))
    return BVH(bounds, node_index, node_count, tri_v, idx, depth, time.perf_counter() - t0)
