"""The binned surface-area-heuristic build of the BVH's node arrays, on all threads.

`node_arrays` orders the primitives' bounds in place and returns the depth-first node arrays that `BVH` holds
(see bvh.py for the layout): a range's top levels are built by one task and its children by others, so the
tree is the single-threaded build's whatever the thread count.
"""
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait

import numba
import numpy as np
from numba import njit

N_BINS = 16
MAX_LEAF = 8
TRAVERSAL_COST = 1.0  # relative to one ray-triangle test
PARALLEL_MIN_TRIANGLES = 20000  # smaller meshes build on one thread
PARALLEL_TASKS = 4  # per thread: ranges of at most n / (threads * 4) triangles are built whole by one task
BOX_STACK = 256  # pending ranges whose bounds are kept from their parent (deeper ones, rare, recompute them)


@njit(cache=True, error_model="numpy")
def surface_area(b):
    """Surface area of a box (lo xyz, hi xyz); 0 for the empty box."""
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
def _build(tri_lo, tri_hi, cent, idx, first, last, n_bins, max_leaf, trav_cost, defer_size):
    """Build the subtree over positions first..last-1, reordering those rows of the primitives' bounds
    `tri_lo`, `tri_hi`, centroids `cent` and triangle ids `idx` together in place: every pass then reads them in
    order (through `idx` the reads scattered once the top levels had split the ranges). Ranges below the root of
    at most `defer_size` (> 0) primitives are not built but left as placeholder nodes (count -1, range in
    `deferred`), so that the caller can build them concurrently: by size, not depth, so that an uneven split
    (a floor beside a million-triangle mesh) still leaves as many similar tasks as threads need. Leaves store
    absolute positions in `idx`. A child's bounds come from its parent's bins and its centroid bounds from the
    partition that made it, so a node reads its rows twice (binning, partition) rather than three times; the
    same bounds bit for bit (min and max are exact)."""
    n = last - first
    max_nodes = 2 * n
    bounds = np.empty((max_nodes, 6))
    node_index = np.zeros(max_nodes, np.int32)
    node_count = np.zeros(max_nodes, np.int32)
    deferred = np.empty((16, 3), np.int64)  # node, start, end; grown as needed
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
    scale = np.empty(3)  # bins per unit of centroid extent on each axis (0: the centroids coincide there)
    while sp > 0:
        sp -= 1
        start, end, parent, depth = st[sp, 0], st[sp, 1], st[sp, 2], st[sp, 3]
        node = n_nodes
        n_nodes += 1
        if parent >= 0:
            node_index[parent] = node
        if defer_size > 0 and depth > 0 and 1 < end - start <= defer_size:
            if n_deferred == deferred.shape[0]:
                more = np.empty((2 * n_deferred, 3), np.int64)
                for r in range(n_deferred):
                    for c in range(3):
                        more[r, c] = deferred[r, c]
                deferred = more
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
        for a in range(3):
            ext = box[a + 3] - box[a]
            scale[a] = n_bins * (1.0 - 1e-9) / ext if ext > 0.0 else 0.0
        # the row's bounds in scalars, loaded once: LLVM cannot tell that the stores into bin_box leave tri_lo
        # and tri_hi alone, so it reloaded them for every axis; an axis whose scale is 0 bins everything into
        # bin 0, which the sweep below skips, instead of a branch per row
        for t in range(start, end):
            x0, y0, z0, x1, y1, z1 = tri_lo[t, 0], tri_lo[t, 1], tri_lo[t, 2], tri_hi[t, 0], tri_hi[t, 1], tri_hi[t, 2]
            for a in range(3):
                j = min(max(int((cent[t, a] - box[a]) * scale[a]), 0), n_bins - 1)
                bin_cnt[a, j] += 1
                bin_box[a, j, 0] = min(bin_box[a, j, 0], x0)
                bin_box[a, j, 1] = min(bin_box[a, j, 1], y0)
                bin_box[a, j, 2] = min(bin_box[a, j, 2], z0)
                bin_box[a, j, 3] = max(bin_box[a, j, 3], x1)
                bin_box[a, j, 4] = max(bin_box[a, j, 4], y1)
                bin_box[a, j, 5] = max(bin_box[a, j, 5], z1)
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
                right_area[j] = surface_area(acc)
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
                cost = c * surface_area(acc) + right_cnt[j + 1] * right_area[j + 1]
                if cost < best_cost:
                    best_cost, best_axis, best_split = cost, a, j
        parent_area = surface_area(bounds[node])
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


def _build_concurrently(lo, hi, cent, idx, n_bins, max_leaf, threads):
    """The tree over all rows as pieces built on `threads` threads: each task builds its range's top levels,
    leaving every child of at most half its size as a placeholder for a new task, until the ranges are small
    enough to build whole (n / (threads * PARALLEL_TASKS)), largest first. So the levels above them run on all
    threads too, not one. Returns `_flatten`'s arrays."""
    n = len(idx)
    whole = n // (threads * PARALLEL_TASKS)
    pieces = []  # (bounds, node_index, node_count, deferred)
    links = []  # per piece: the piece ids that fill its placeholders, in `deferred` order

    def task(first, last):
        size = last - first
        return _build(lo, hi, cent, idx, first, last, n_bins, max_leaf, TRAVERSAL_COST,
                      max(size // 2, whole) if size > whole else 0)

    with ThreadPoolExecutor(threads) as pool:
        pending = {pool.submit(task, 0, n): (-1, -1)}
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                parent, row = pending.pop(future)
                piece = len(pieces)
                pieces.append(future.result())
                deferred = pieces[-1][3]
                links.append([-1] * len(deferred))
                if parent >= 0:
                    links[parent][row] = piece
                for r in np.argsort(deferred[:, 1] - deferred[:, 2], kind="stable"):
                    pending[pool.submit(task, deferred[r, 1], deferred[r, 2])] = (piece, r)
    return _flatten(pieces, links)


@njit(cache=True, error_model="numpy")
def _place(bounds, node_index, node_count, final, out_b, out_i, out_c):
    """Copy a piece's nodes (all but its placeholders) to their final positions, links made final too."""
    for i in range(bounds.shape[0]):
        if node_count[i] == -1:
            continue
        f = final[i]
        for k in range(6):
            out_b[f, k] = bounds[i, k]
        out_c[f] = node_count[i]
        out_i[f] = final[node_index[i]] if node_count[i] == 0 else node_index[i]


def _flatten(pieces, links):
    """One set of depth-first node arrays from the pieces, each placeholder replaced by the piece built for it:
    the arrays a single-threaded build produces, each piece copied once."""
    sizes = [0] * len(pieces)
    for p in reversed(range(len(pieces))):  # a piece's children were built after it
        sizes[p] = len(pieces[p][0]) + sum(sizes[c] - 1 for c in links[p])
    out_b = np.empty((sizes[0], 6))
    out_i = np.empty(sizes[0], np.int32)
    out_c = np.empty(sizes[0], np.int32)
    todo = [(0, 0)]  # piece, its root's final position
    while todo:
        p, base = todo.pop()
        bounds, node_index, node_count, deferred = pieces[p]
        shift = np.zeros(len(bounds) + 1, np.int64)
        shift[deferred[:, 0] + 1] = [sizes[c] - 1 for c in links[p]]
        final = base + np.arange(len(bounds)) + np.cumsum(shift)[:-1]
        _place(bounds, node_index, node_count, final, out_b, out_i, out_c)
        todo.extend((c, int(final[node])) for c, node in zip(links[p], deferred[:, 0]))
    return out_b, out_i, out_c


def node_arrays(lo, hi, cent, idx, n_bins, max_leaf):
    """Bounds (nodes, 6), right child or first primitive, and leaf primitive count of the tree over the
    primitives' bounds `lo`, `hi` and centroids `cent` (n, 3), whose rows are reordered with `idx` in place."""
    n = len(idx)
    threads = numba.get_num_threads()
    if n >= PARALLEL_MIN_TRIANGLES and threads > 1:
        return _build_concurrently(lo, hi, cent, idx, n_bins, max_leaf, threads)
    bounds, node_index, node_count, _ = _build(lo, hi, cent, idx, 0, n, n_bins, max_leaf, TRAVERSAL_COST, 0)
    return bounds.copy(), node_index.copy(), node_count.copy()  # views of buffers sized for the worst case
