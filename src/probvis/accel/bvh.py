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
BOX_STACK = 256  # pending ranges whose bounds are kept from their parent (deeper ones, rare, recompute them)


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


@njit(cache=True, error_model="numpy", inline="always")
def _bins_union(bin_box, axis, first, last, out, row):
    """The union of the boxes of bins first..last-1 on `axis`, into out[row, :6]."""
    for k in range(3):
        out[row, k] = np.inf
        out[row, k + 3] = -np.inf
    for j in range(first, last):
        for k in range(3):
            out[row, k] = min(out[row, k], bin_box[axis, j, k])
            out[row, k + 3] = max(out[row, k + 3], bin_box[axis, j, k + 3])


@njit(cache=True, error_model="numpy", nogil=True)
def _build(tri_lo, tri_hi, cent, idx, first, last, n_bins, max_leaf, trav_cost, defer_depth):
    """Build the subtree over positions first..last-1, reordering those rows of the primitives' bounds
    `tri_lo`, `tri_hi`, centroids `cent` and triangle ids `idx` together in place: every pass then reads them in
    order (through `idx` the reads scattered once the top levels had split the ranges). Ranges reached at depth
    `defer_depth` (> 0) are not built but left as placeholder nodes (count -1, range in `deferred`), so that
    the caller can build them concurrently. Leaves store absolute positions in `idx`. A child's bounds come
    from its parent's bins and its centroid bounds from the partition that made it, so a node reads its rows
    twice (binning, partition) rather than three times; the same bounds bit for bit (min and max are exact)."""
    n = last - first
    max_nodes = 2 * n
    bounds = np.empty((max_nodes, 6))
    node_index = np.zeros(max_nodes, np.int32)
    node_count = np.zeros(max_nodes, np.int32)
    deferred = np.empty((max(1, 1 << max(defer_depth, 0)), 3), np.int64)  # node, start, end
    n_deferred = 0
    # pending ranges: start, end, parent (right-child links are patched when the node is created), depth
    # (start, end, parent, depth, bounds known) of each pending range, grown as the tree deepens
    st = np.empty((BOX_STACK, 5), np.int64)
    st_box = np.empty((BOX_STACK, 12))  # a pending range's bounds and centroid bounds, when known
    st[0, 0], st[0, 1], st[0, 2], st[0, 3], st[0, 4] = first, last, -1, 0, 0
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
        start, end, parent, depth = st[sp, 0], st[sp, 1], st[sp, 2], st[sp, 3]
        node = n_nodes
        n_nodes += 1
        if parent >= 0:
            node_index[parent] = node
        if defer_depth > 0 and depth == defer_depth and end - start > 1:
            node_count[node] = -1
            deferred[n_deferred, 0], deferred[n_deferred, 1], deferred[n_deferred, 2] = node, start, end
            n_deferred += 1
            continue
        if st[sp, 4]:
            for k in range(6):
                bounds[node, k] = st_box[sp, k]
                box[k] = st_box[sp, 6 + k]
        else:
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
        mid = -1
        # the children's centroid bounds, gathered as the partition classifies each row once
        l0x = l0y = l0z = r0x = r0y = r0z = np.inf
        l1x = l1y = l1z = r1x = r1y = r1z = -np.inf
        if best_axis >= 0:
            lo, hi = start, end - 1
            while lo <= hi:
                px, py, pz = cent[lo, 0], cent[lo, 1], cent[lo, 2]
                j = min(max(int((cent[lo, best_axis] - box[best_axis]) * scale[best_axis]), 0), n_bins - 1)
                if j <= best_split:
                    l0x, l0y, l0z = min(l0x, px), min(l0y, py), min(l0z, pz)
                    l1x, l1y, l1z = max(l1x, px), max(l1y, py), max(l1z, pz)
                    lo += 1
                else:
                    r0x, r0y, r0z = min(r0x, px), min(r0y, py), min(r0z, pz)
                    r1x, r1y, r1z = max(r1x, px), max(r1y, py), max(r1z, pz)
                    _swap_rows(tri_lo, tri_hi, cent, idx, lo, hi)
                    hi -= 1
            mid = lo
        known = start < mid < end and sp + 1 < BOX_STACK
        if not start < mid < end:
            mid = (start + end) // 2  # all centroids coincide: split by count
        node_count[node] = 0
        if sp + 2 > st.shape[0]:
            grown = np.empty((2 * st.shape[0], 5), np.int64)
            for r in range(sp):  # element by element: a slice copy's shape check compiles for seconds
                for c in range(5):
                    grown[r, c] = st[r, c]
            st = grown
        st[sp, 0], st[sp, 1], st[sp, 2], st[sp, 3], st[sp, 4] = mid, end, node, depth + 1, known
        if known:  # the right child's bounds: its bins' union
            _bins_union(bin_box, best_axis, best_split + 1, n_bins, st_box, sp)
            st_box[sp, 6], st_box[sp, 7], st_box[sp, 8] = r0x, r0y, r0z
            st_box[sp, 9], st_box[sp, 10], st_box[sp, 11] = r1x, r1y, r1z
        sp += 1
        st[sp, 0], st[sp, 1], st[sp, 2], st[sp, 3], st[sp, 4] = start, mid, -1, depth + 1, known
        if known:
            _bins_union(bin_box, best_axis, 0, best_split + 1, st_box, sp)
            st_box[sp, 6], st_box[sp, 7], st_box[sp, 8] = l0x, l0y, l0z
            st_box[sp, 9], st_box[sp, 10], st_box[sp, 11] = l1x, l1y, l1z
        sp += 1
    return bounds[:n_nodes], node_index[:n_nodes], node_count[:n_nodes], deferred[:n_deferred]


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
    n = len(tris)
    lo, hi, cent, idx = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty(n, np.int32)
    _primitive_bounds(tris, lo, hi, cent, idx)
    threads = numba.get_num_threads()
    defer = PARALLEL_DEPTH if n >= PARALLEL_MIN_TRIANGLES and threads > 1 else 0
    bounds, node_index, node_count, deferred = _build(lo, hi, cent, idx, 0, n, n_bins, max_leaf, TRAVERSAL_COST,
                                                      defer)
    if len(deferred):
        with ThreadPoolExecutor(threads) as pool:
            subtrees = list(pool.map(lambda d: _build(lo, hi, cent, idx, d[1], d[2], n_bins, max_leaf,
                                                      TRAVERSAL_COST, 0), deferred))
        bounds, node_index, node_count = _splice(bounds, node_index, node_count, deferred, subtrees)
    else:  # views of buffers sized for the worst case: keep only what the tree uses
        bounds, node_index, node_count = bounds.copy(), node_index.copy(), node_count.copy()
    tri_v = np.empty_like(tris)
    _gather(tris, idx, tri_v)
    depth = int(_depth_stats(node_index, node_count))
    return BVH(bounds, node_index, node_count, tri_v, idx, depth, time.perf_counter() - t0)
