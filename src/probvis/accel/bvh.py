"""Bounding volume hierarchy over triangles, built top-down with the binned surface-area heuristic.

Layout (depth-first): the left child of interior node i is i + 1; `node_index[i]` is the right child of an
interior node or the first primitive of a leaf; `node_count[i]` is 0 for interior nodes and the number of
primitives of a leaf.
Triangle vertices are stored in BVH order in `tri_v`; `prim_ids` maps BVH order back to scene triangle ids.
"""
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np
from numba import njit, prange

N_BINS = 16
MAX_LEAF = 8
TRAVERSAL_COST = 1.0  # relative to one ray-triangle test
PARALLEL_MIN_TRIANGLES = 20000  # smaller meshes build on one thread
PARALLEL_DEPTH = 3  # subtrees below this depth (up to 8) are built concurrently


@njit(cache=True, error_model="numpy")
def _area(b):
    dx, dy, dz = b[3] - b[0], b[4] - b[1], b[5] - b[2]
    if dx < 0.0:
        return 0.0
    return 2.0 * (dx * dy + dy * dz + dz * dx)


@njit(cache=True, error_model="numpy", inline="always")
def _swap_rows(tri_lo, tri_hi, cent, idx, a, b):
    idx[a], idx[b] = idx[b], idx[a]
    for k in range(3):
        tri_lo[a, k], tri_lo[b, k] = tri_lo[b, k], tri_lo[a, k]
        tri_hi[a, k], tri_hi[b, k] = tri_hi[b, k], tri_hi[a, k]
        cent[a, k], cent[b, k] = cent[b, k], cent[a, k]


@njit(cache=True, error_model="numpy", nogil=True)
def _build(tri_lo, tri_hi, cent, idx, first, last, n_bins, max_leaf, trav_cost, defer_depth):
    """Build the subtree over positions first..last-1, reordering those rows of the primitives' bounds
    `tri_lo`, `tri_hi`, centroids `cent` and triangle ids `idx` together in place: every pass then reads them in
    order (through `idx` the reads scattered once the top levels had split the ranges). Ranges reached at depth
    `defer_depth` (> 0) are not built but left as placeholder nodes (count -1, range in `deferred`), so that
    the caller can build them concurrently. Leaves store absolute positions in `idx`."""
    n = last - first
    max_nodes = 2 * n
    bounds = np.empty((max_nodes, 6))
    node_index = np.zeros(max_nodes, np.int32)
    node_count = np.zeros(max_nodes, np.int32)
    deferred = np.empty((max(1, 1 << max(defer_depth, 0)), 3), np.int64)  # node, start, end
    n_deferred = 0
    # pending ranges: start, end, parent (right-child links are patched when the node is created), depth
    st_start = np.empty(n + 64, np.int64)
    st_end = np.empty(n + 64, np.int64)
    st_parent = np.empty(n + 64, np.int64)
    st_depth = np.empty(n + 64, np.int64)
    st_start[0], st_end[0], st_parent[0], st_depth[0] = first, last, -1, 0
    sp = 1
    n_nodes = 0
    bin_cnt = np.zeros((3, n_bins), np.int64)
    bin_box = np.empty((3, n_bins, 6))
    right_area = np.empty(n_bins)
    right_cnt = np.empty(n_bins, np.int64)
    box = np.empty(6)
    acc = np.empty(6)
    while sp > 0:
        sp -= 1
        start, end, parent, depth = st_start[sp], st_end[sp], st_parent[sp], st_depth[sp]
        node = n_nodes
        n_nodes += 1
        if parent >= 0:
            node_index[parent] = node
        if defer_depth > 0 and depth == defer_depth and end - start > 1:
            node_count[node] = -1
            deferred[n_deferred, 0], deferred[n_deferred, 1], deferred[n_deferred, 2] = node, start, end
            n_deferred += 1
            continue
        # node bounds and centroid bounds, accumulated in scalars: min/max into array elements would be a
        # chain of stores and reloads (LLVM cannot keep them in registers past the loads of tri_lo)
        lx = ly = lz = cx0 = cy0 = cz0 = np.inf
        hx = hy = hz = cx1 = cy1 = cz1 = -np.inf
        for t in range(start, end):
            lx, ly, lz = min(lx, tri_lo[t, 0]), min(ly, tri_lo[t, 1]), min(lz, tri_lo[t, 2])
            hx, hy, hz = max(hx, tri_hi[t, 0]), max(hy, tri_hi[t, 1]), max(hz, tri_hi[t, 2])
            cx0, cy0, cz0 = min(cx0, cent[t, 0]), min(cy0, cent[t, 1]), min(cz0, cent[t, 2])
            cx1, cy1, cz1 = max(cx1, cent[t, 0]), max(cy1, cent[t, 1]), max(cz1, cent[t, 2])
        bounds[node, 0], bounds[node, 1], bounds[node, 2] = lx, ly, lz
        bounds[node, 3], bounds[node, 4], bounds[node, 5] = hx, hy, hz
        box[0], box[1], box[2], box[3], box[4], box[5] = cx0, cy0, cz0, cx1, cy1, cz1
        count = end - start
        if count <= 1:
            node_index[node], node_count[node] = start, count
            continue
        # binning on all three axes
        bin_cnt[:, :] = 0
        for a in range(3):
            for j in range(n_bins):
                for k in range(3):
                    bin_box[a, j, k] = np.inf
                    bin_box[a, j, k + 3] = -np.inf
        scale = np.zeros(3)
        for a in range(3):
            ext = box[a + 3] - box[a]
            if ext > 0.0:
                scale[a] = n_bins * (1.0 - 1e-9) / ext
        for t in range(start, end):
            for a in range(3):
                if scale[a] == 0.0:
                    continue
                j = int((cent[t, a] - box[a]) * scale[a])
                j = min(max(j, 0), n_bins - 1)
                bin_cnt[a, j] += 1
                for k in range(3):
                    bin_box[a, j, k] = min(bin_box[a, j, k], tri_lo[t, k])
                    bin_box[a, j, k + 3] = max(bin_box[a, j, k + 3], tri_hi[t, k])
        best_cost = np.inf
        best_axis = -1
        best_split = -1
        for a in range(3):
            if scale[a] == 0.0:
                continue
            for k in range(3):
                acc[k] = np.inf
                acc[k + 3] = -np.inf
            c = 0
            for j in range(n_bins - 1, 0, -1):
                c += bin_cnt[a, j]
                for k in range(3):
                    acc[k] = min(acc[k], bin_box[a, j, k])
                    acc[k + 3] = max(acc[k + 3], bin_box[a, j, k + 3])
                right_area[j] = _area(acc)
                right_cnt[j] = c
            for k in range(3):
                acc[k] = np.inf
                acc[k + 3] = -np.inf
            c = 0
            for j in range(n_bins - 1):
                c += bin_cnt[a, j]
                for k in range(3):
                    acc[k] = min(acc[k], bin_box[a, j, k])
                    acc[k + 3] = max(acc[k + 3], bin_box[a, j, k + 3])
                if c == 0 or right_cnt[j + 1] == 0:
                    continue
                cost = c * _area(acc) + right_cnt[j + 1] * right_area[j + 1]
                if cost < best_cost:
                    best_cost, best_axis, best_split = cost, a, j
        parent_area = _area(bounds[node])
        split_cost = trav_cost + best_cost / parent_area if parent_area > 0.0 else np.inf
        if count <= max_leaf and (best_axis < 0 or split_cost >= count):
            node_index[node], node_count[node] = start, count
            continue
        if best_axis >= 0:
            lo, hi = start, end - 1
            while lo <= hi:
                j = min(max(int((cent[lo, best_axis] - box[best_axis]) * scale[best_axis]), 0), n_bins - 1)
                if j <= best_split:
                    lo += 1
                else:
                    _swap_rows(tri_lo, tri_hi, cent, idx, lo, hi)
                    hi -= 1
            mid = lo
        else:
            mid = -1
        if mid <= start or mid >= end:
            mid = (start + end) // 2  # all centroids coincide: split by count
        node_count[node] = 0
        st_start[sp], st_end[sp], st_parent[sp], st_depth[sp] = mid, end, node, depth + 1
        sp += 1
        st_start[sp], st_end[sp], st_parent[sp], st_depth[sp] = start, mid, -1, depth + 1
        sp += 1
    return bounds[:n_nodes].copy(), node_index[:n_nodes].copy(), node_count[:n_nodes].copy(), \
        deferred[:n_deferred].copy()


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
        leaves = self.node_count > 0
        root_area = float(_area(self.bounds[0]))
        areas = 2.0 * np.sum(np.stack([
            (self.bounds[:, 3] - self.bounds[:, 0]) * (self.bounds[:, 4] - self.bounds[:, 1]),
            (self.bounds[:, 4] - self.bounds[:, 1]) * (self.bounds[:, 5] - self.bounds[:, 2]),
            (self.bounds[:, 5] - self.bounds[:, 2]) * (self.bounds[:, 3] - self.bounds[:, 0])]), axis=0)
        sah = (TRAVERSAL_COST * areas[~leaves].sum() + (areas[leaves] * self.node_count[leaves]).sum()) / root_area
        return {
            "nodes": int(len(self.node_count)),
            "leaves": int(leaves.sum()),
            "max_depth": self.max_depth,
            "mean_leaf_size": float(self.node_count[leaves].mean()),
            "max_leaf_size": int(self.node_count.max()),
            "sah_cost": float(sah),
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


def _splice(bounds, node_index, node_count, deferred, subtrees):
    """The depth-first node arrays of the top tree with each placeholder replaced by its subtree: the same
    arrays a single-threaded build produces."""
    top = len(bounds)
    sizes = np.array([len(sub[0]) for sub in subtrees], np.int64)
    shift = np.zeros(top + 1, np.int64)
    np.add.at(shift, deferred[:, 0] + 1, sizes - 1)
    final = np.arange(top) + np.cumsum(shift)[:top]
    total = top + int((sizes - 1).sum())
    out_b = np.empty((total, 6))
    out_i = np.empty(total, np.int32)
    out_c = np.empty(total, np.int32)
    keep = node_count != -1
    inner = keep & (node_count == 0)
    out_b[final[keep]] = bounds[keep]
    out_c[final[keep]] = node_count[keep]
    out_i[final[keep]] = node_index[keep]
    out_i[final[inner]] = final[node_index[inner]]
    for (node, _, _), (b, ni, nc, _) in zip(deferred, subtrees):
        base = final[node]
        out_b[base:base + len(b)] = b
        out_c[base:base + len(b)] = nc
        out_i[base:base + len(b)] = np.where(nc == 0, ni + base, ni)
    return out_b, out_i, out_c


def build_bvh(triangles, n_bins=N_BINS, max_leaf=MAX_LEAF):
    """Build a BVH over `triangles` (n, 3, 3) float64. Large meshes build the top levels first and the
    subtrees below them on all threads; the tree is the same as a single-threaded build's."""
    tris = np.ascontiguousarray(triangles, dtype=np.float64)
    t0 = time.perf_counter()
    lo = np.minimum(np.minimum(tris[:, 0], tris[:, 1]), tris[:, 2])  # 7x faster than tris.min(axis=1)
    hi = np.maximum(np.maximum(tris[:, 0], tris[:, 1]), tris[:, 2])
    cent = 0.5 * (lo + hi)
    n = len(tris)
    idx = np.arange(n, dtype=np.int32)
    threads = numba.get_num_threads()
    defer = PARALLEL_DEPTH if n >= PARALLEL_MIN_TRIANGLES and threads > 1 else 0
    bounds, node_index, node_count, deferred = _build(lo, hi, cent, idx, 0, n, n_bins, max_leaf, TRAVERSAL_COST,
                                                      defer)
    if len(deferred):
        with ThreadPoolExecutor(threads) as pool:
            subtrees = list(pool.map(lambda d: _build(lo, hi, cent, idx, d[1], d[2], n_bins, max_leaf,
                                                      TRAVERSAL_COST, 0), deferred))
        bounds, node_index, node_count = _splice(bounds, node_index, node_count, deferred, subtrees)
    tri_v = np.ascontiguousarray(tris[idx])
    depth = int(_depth_stats(node_index, node_count))
    return BVH(bounds, node_index, node_count, tri_v, idx, depth, time.perf_counter() - t0)
