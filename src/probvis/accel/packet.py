"""Traversal of ray packets: up to 64 coherent rays, traversed together.

A packet is either the shadow segments of one shading point (towards one emitter: nearly parallel, one
origin) or a run of 64 camera rays (4 neighbouring pixels' samples, all from the camera's origin). A packet
fetches each node once, tests both child boxes against all of its rays in one loop that LLVM turns into SIMD
code (computing box-minus-origin once when all rays share their origin), and descends with a bit mask of the
rays whose boxes were hit. Where the mask has thinned to a few rays (SPARSE_RAYS, or a quarter of the packet),
as deep in foliage where the rays of one point part ways, the node tests those rays alone, and leaves visit the
mask's set bits only: the same tests in the same order, without a loop over the whole packet per node (leaves
and heavy-scan 1.25-1.3x on one thread, bench/bench_embree_replay.py). Every ray still makes only box and
triangle tests it would make alone (a ray only follows the nodes whose boxes it hits; in an any-hit query it
leaves the packet at its first hit), in the packet's visiting order: an occluded ray may find a different
blocker first, and a nearest-hit ray may test boxes that its own order would have culled. Results are those
of `traversal.any_hit` and `traversal.closest_hit`.
"""
import numpy as np
from numba import njit

from ..parallel import over_lanes
from .traversal import _BOX_SLACK, hit_triangle, ray_setup, triangle_blocks

MAX_PACKET = 64  # rays per packet: one bit each in a uint64 mask
# shadow segments of one shading point per packet: they fan out to the emitter, so beyond this a packet visits
# more nodes than its rays need (heavy-scan at 64 shadow rays: 3.9 s at 64, 3.0 s at 32, see docs/decisions.md)
SHADOW_PACKET = 32
PACKETS_PER_TASK = 8
SPARSE_RAYS = 4  # a node reached by at most this many of a packet's rays (or a quarter) tests them one by one
_BIG = 1e300  # reciprocal of a zero direction component: finite, so an axis-parallel ray gives no NaN


@njit(cache=True, error_model="numpy")
def packet_starts(point, max_size=SHADOW_PACKET):
    """Packet boundaries for segments sorted by shading point: a packet is a run of equal `point` values,
    cut every `max_size` segments. Returns (packets + 1,) int64 offsets."""
    n = point.shape[0]
    starts = np.empty(n + 1, np.int64)
    k = 0
    first = 0
    for i in range(n):
        if i == 0 or point[i] != point[i - 1] or i - first == max_size:
            starts[k] = i
            k += 1
            first = i
    starts[k] = n
    return starts[:k + 1].copy()


@njit(cache=True, error_model="numpy", inline="always")
def _slab_entry(a0, a1, c0, c1, e0, e1, t_lo, t_hi):
    """Entry distance into a box from the slab distances of its six planes, inf on a miss in [t_lo, t_hi]."""
    t0 = max(max(min(a0, a1), min(c0, c1)), max(min(e0, e1), t_lo))
    t1 = min(min(max(a0, a1), max(c0, c1)), max(e0, e1)) * _BOX_SLACK
    t1 = min(t1, t_hi)
    return t0 if t0 <= t1 else np.inf


@njit(cache=True, error_model="numpy", inline="always")
def _child_boxes(b, node, m, rays, shared, t_left, t_right):
    """Entry distances of rays 0..m-1 (columns of `rays`) into both boxes of record `node`, inf on a miss.
    With `shared` all rays start at the first one's origin, and box-minus-origin is computed once."""
    if shared:
        ox, oy, oz = rays[0, 0], rays[1, 0], rays[2, 0]
        ax0, ay0, az0, ax1, ay1, az1 = b[node, 0] - ox, b[node, 1] - oy, b[node, 2] - oz, b[node, 3] - ox, \
            b[node, 4] - oy, b[node, 5] - oz
        bx0, by0, bz0, bx1, by1, bz1 = b[node, 6] - ox, b[node, 7] - oy, b[node, 8] - oz, b[node, 9] - ox, \
            b[node, 10] - oy, b[node, 11] - oz
        for r in range(m):
            ix, iy, iz, t_lo, t_hi = rays[3, r], rays[4, r], rays[5, r], rays[6, r], rays[7, r]
            t_left[r] = _slab_entry(ax0 * ix, ax1 * ix, ay0 * iy, ay1 * iy, az0 * iz, az1 * iz, t_lo, t_hi)
            t_right[r] = _slab_entry(bx0 * ix, bx1 * ix, by0 * iy, by1 * iy, bz0 * iz, bz1 * iz, t_lo, t_hi)
        return
    ax0, ay0, az0, ax1, ay1, az1 = b[node, 0], b[node, 1], b[node, 2], b[node, 3], b[node, 4], b[node, 5]
    bx0, by0, bz0, bx1, by1, bz1 = b[node, 6], b[node, 7], b[node, 8], b[node, 9], b[node, 10], b[node, 11]
    for r in range(m):
        ox, oy, oz = rays[0, r], rays[1, r], rays[2, r]
        ix, iy, iz, t_lo, t_hi = rays[3, r], rays[4, r], rays[5, r], rays[6, r], rays[7, r]
        t_left[r] = _slab_entry((ax0 - ox) * ix, (ax1 - ox) * ix, (ay0 - oy) * iy, (ay1 - oy) * iy,
                                (az0 - oz) * iz, (az1 - oz) * iz, t_lo, t_hi)
        t_right[r] = _slab_entry((bx0 - ox) * ix, (bx1 - ox) * ix, (by0 - oy) * iy, (by1 - oy) * iy,
                                 (bz0 - oz) * iz, (bz1 - oz) * iz, t_lo, t_hi)


_DEBRUIJN = 0x03F79D71B4CB0A89  # a de Bruijn sequence: the top 6 bits of 2^i times it differ for every i < 64


def _bit_index_table():
    table = np.zeros(64, np.int64)
    for i in range(64):
        table[((1 << i) * _DEBRUIJN % (1 << 64)) >> 58] = i
    return table


_BIT_INDEX = _bit_index_table()  # the index of a uint64's one set bit b: _BIT_INDEX[(b * _DEBRUIJN) >> 58]


@njit(cache=True, error_model="numpy", inline="always")
def _lowest(bits):
    """Index of the lowest set bit of a uint64 (0 for 0)."""
    return _BIT_INDEX[((bits & (~bits + np.uint64(1))) * np.uint64(_DEBRUIJN)) >> np.uint64(58)]


@njit(cache=True, error_model="numpy", inline="always")
def _popcount(x):
    """Set bits of a uint64."""
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return np.int64((x * np.uint64(0x0101010101010101)) >> np.uint64(56))


@njit(cache=True, error_model="numpy", inline="always")
def _one_child_boxes(b, node, r, rays, t_left, t_right):
    """`_child_boxes` of ray r alone (the same arithmetic: a shared origin is the ray's own)."""
    ox, oy, oz = rays[0, r], rays[1, r], rays[2, r]
    ix, iy, iz, t_lo, t_hi = rays[3, r], rays[4, r], rays[5, r], rays[6, r], rays[7, r]
    t_left[r] = _slab_entry((b[node, 0] - ox) * ix, (b[node, 3] - ox) * ix, (b[node, 1] - oy) * iy,
                            (b[node, 4] - oy) * iy, (b[node, 2] - oz) * iz, (b[node, 5] - oz) * iz, t_lo, t_hi)
    t_right[r] = _slab_entry((b[node, 6] - ox) * ix, (b[node, 9] - ox) * ix, (b[node, 7] - oy) * iy,
                             (b[node, 10] - oy) * iy, (b[node, 8] - oz) * iz, (b[node, 11] - oz) * iz, t_lo, t_hi)


@njit(cache=True, error_model="numpy")
def _trace_packet(cb, ci, root2, tv, org, dirs, tmin, tmax, lo, m, rays, t_left, t_right, visits, stack,
                  stack_mask, closest, occ, hit, hit_t, hit_b1, hit_b2, n_node, n_tri):
    """Traversal of rays lo..lo+m-1 (m <= 64); fills their `n_node` and `n_tri`. With `closest` (a constant
    in each caller, so the other case compiles away) it finds each ray's nearest hit and fills `hit` (BVH-order
    triangle or -1), `hit_t` (inf for none), `hit_b1` and `hit_b2`; else it fills `occ`, a ray leaving the
    packet at its first hit. The arrays of the other case are not touched."""
    one = np.uint64(1)
    shared = True  # all rays leave one point (camera rays of a pinhole camera, shadow rays of one shading point)
    for r in range(m):
        i = lo + r
        dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        rays[0, r], rays[1, r], rays[2, r] = org[i, 0], org[i, 1], org[i, 2]
        rays[3, r] = 1.0 / dx if dx != 0.0 else _BIG
        rays[4, r] = 1.0 / dy if dy != 0.0 else _BIG
        rays[5, r] = 1.0 / dz if dz != 0.0 else _BIG
        rays[6, r], rays[7, r] = tmin[i], tmax[i]
        visits[r] = 0
        shared &= org[i, 0] == org[lo, 0] and org[i, 1] == org[lo, 1] and org[i, 2] == org[lo, 2]
        if closest:
            hit[i], hit_t[i] = -1, np.inf
        else:
            occ[i] = False
        n_tri[i] = 0
    _child_boxes(root2, 0, m, rays, shared, t_left, t_right)  # the root's box, stored as both children of one record
    alive = np.uint64(0)
    for r in range(m):
        if t_left[r] < np.inf:
            alive |= one << np.uint64(r)
    mask = alive
    sp = 0
    node = 0
    while True:
        mask &= alive
        if mask != 0:
            cnt = ci[node, 13]
            if cnt == 0:
                left = np.uint64(0)
                right = np.uint64(0)
                if _popcount(mask) <= max(SPARSE_RAYS, m // 4):  # few rays left in the packet: test those alone
                    bits = mask
                    while bits != 0:
                        r = _lowest(bits)
                        bits &= bits - one
                        sh = np.uint64(r)
                        visits[r] += 1
                        _one_child_boxes(cb, node, r, rays, t_left, t_right)
                        left |= np.uint64(t_left[r] < np.inf) << sh
                        right |= np.uint64(t_right[r] < np.inf) << sh
                else:
                    _child_boxes(cb, node, m, rays, shared, t_left, t_right)
                    for r in range(m):
                        sh = np.uint64(r)
                        inside = (mask >> sh) & one
                        visits[r] += inside
                        left |= (np.uint64(t_left[r] < np.inf) & inside) << sh
                        right |= (np.uint64(t_right[r] < np.inf) & inside) << sh
                if left != 0 and right != 0:
                    both = left & right
                    r0 = _lowest(both)  # 0 if both is 0
                    # nearer child first, as seen by the first ray that hits both (left first if none does)
                    if both == 0 or t_left[r0] <= t_right[r0]:
                        stack[sp], stack_mask[sp] = ci[node, 12], right
                        node, mask = node + 1, left
                    else:
                        stack[sp], stack_mask[sp] = node + 1, left
                        node, mask = ci[node, 12], right
                    sp += 1
                    continue
                if left != 0:
                    node, mask = node + 1, left
                    continue
                if right != 0:
                    node, mask = ci[node, 12], right
                    continue
            else:
                first = ci[node, 12]
                bits = mask
                while bits != 0:
                    r = _lowest(bits)
                    bits &= bits - one
                    bit = one << np.uint64(r)
                    o = (rays[0, r], rays[1, r], rays[2, r])
                    # the triangle test's shear, only for the few rays that reach a leaf (saves divisions)
                    kx, ky, kz, sx, sy, sz = ray_setup(dirs[lo + r, 0], dirs[lo + r, 1], dirs[lo + r, 2])
                    for p in range(first, first + cnt):
                        n_tri[lo + r] += 1
                        if not closest:
                            if triangle_blocks(tv, p, o, kx, ky, kz, sx, sy, sz, rays[6, r], rays[7, r]):
                                occ[lo + r] = True
                                alive &= ~bit
                                break
                            continue
                        t, u, v = hit_triangle(tv, p, o, kx, ky, kz, sx, sy, sz, rays[6, r], rays[7, r])
                        if t < rays[7, r]:
                            rays[7, r] = t  # later boxes and triangles are culled against the nearer hit
                            hit[lo + r], hit_t[lo + r], hit_b1[lo + r], hit_b2[lo + r] = p, t, u, v
        if sp == 0 or alive == 0:
            break
        sp -= 1
        node, mask = stack[sp], stack_mask[sp]
    for r in range(m):
        n_node[lo + r] = 1 + 2 * np.int64(visits[r])


@njit(cache=True, error_model="numpy", inline="always")
def packet_work(depth):
    """Work arrays of packet traversals, made once per parallel work item: ray constants, child entry
    distances, visit counts, and the node and mask stacks of a BVH of that depth."""
    return (np.empty((8, MAX_PACKET)), np.empty(MAX_PACKET), np.empty(MAX_PACKET), np.empty(MAX_PACKET, np.uint64),
            np.empty(depth, np.int64), np.empty(depth, np.uint64))


@njit(cache=True, error_model="numpy", inline="always")
def occluded_packet(bvh, root2, org, dirs, tmin, tmax, lo, m, work, occ, n_node, n_tri):
    """Any-hit traversal of the packet of segments lo..lo+m-1 (m <= 64): fills their `occ`, `n_node` and
    `n_tri`. `root2` is `root_record(bvh.root)` and `work` is `packet_work(bvh.stack_depth)`."""
    rays, t_left, t_right, visits, stack, stack_mask = work
    _trace_packet(bvh.records, bvh.ints, root2, bvh.tri_v, org, dirs, tmin, tmax, lo, m, rays, t_left, t_right, visits,
                  stack, stack_mask, False, occ, n_node, tmax, tmax, tmax, n_node, n_tri)


@njit(cache=True, error_model="numpy", inline="always")
def _trace_task(bvh, root2, org, dirs, tmin, tmax, starts, task, closest, occ, hit, hit_t, hit_b1, hit_b2, n_node,
                n_tri, work):
    """Packets task * PACKETS_PER_TASK onwards (one parallel work item), with the thread's `packet_work`."""
    rays, t_left, t_right, visits, stack, stack_mask = work
    cb, ci, tv = bvh.records, bvh.ints, bvh.tri_v
    for k in range(task * PACKETS_PER_TASK, min(starts.shape[0] - 1, (task + 1) * PACKETS_PER_TASK)):
        _trace_packet(cb, ci, root2, tv, org, dirs, tmin, tmax, starts[k], starts[k + 1] - starts[k], rays, t_left,
                      t_right, visits, stack, stack_mask, closest, occ, hit, hit_t, hit_b1, hit_b2, n_node, n_tri)


@njit(cache=True, error_model="numpy", inline="always")
def root_record(root):
    """The root's box stored as both children of one record, so the first test uses the node-pair code."""
    root2 = np.empty((1, 12))
    for c in range(6):  # element by element: a slice copy's shape check compiles for seconds
        root2[0, c] = root2[0, 6 + c] = root[0, c]
    return root2


def any_hit_packets(bvh, org, dirs, tmin, tmax, starts):
    """Occlusion queries over packets [starts[k], starts[k + 1]) of at most 64 segments: occluded flag, node
    and triangle tests per segment."""
    n = org.shape[0]
    out = (np.empty(n, np.bool_), np.empty(n, np.int32), np.empty(n, np.int32))
    _over_tasks(_any_hit_tasks, bvh, (org, dirs, tmin, tmax, starts), out)
    return out


def closest_hit_packets(bvh, org, dirs, tmin, tmax, starts):
    """Nearest hits over packets [starts[k], starts[k + 1]) of at most 64 rays, returned as by
    `traversal.closest_hit`: scene triangle id (-1 on a miss), t, b1, b2, node and triangle tests."""
    n = org.shape[0]
    hit, t, b1, b2 = np.empty(n, np.int64), np.empty(n), np.zeros(n), np.zeros(n)
    n_node, n_tri = np.empty(n, np.int32), np.empty(n, np.int32)
    out = (np.empty(0, np.bool_), hit, t, b1, b2, n_node, n_tri)  # an empty stand-in for the occlusion flags
    _over_tasks(_closest_hit_tasks, bvh, (org, dirs, tmin, tmax, starts), out)
    prim = np.full(n, -1, np.int32)
    found = hit >= 0
    prim[found] = bvh.prim_ids[hit[found]]
    return prim, t, b1, b2, n_node, n_tri


def _over_tasks(kernel, bvh, rays, out):
    """Run a serial packet kernel over the thread budget, each thread with work arrays of its own (the kernels
    run without Numba's allocator and reference counts, as `fused_exact`'s)."""
    root2 = root_record(bvh.root)
    n_tasks = (rays[4].shape[0] - 1 + PACKETS_PER_TASK - 1) // PACKETS_PER_TASK
    over_lanes(lambda lane, lanes: kernel(bvh, root2, rays, lane, lanes, out, packet_work(bvh.stack_depth)), n_tasks)


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def _any_hit_tasks(bvh, root2, rays, lane, lanes, out, work):
    """Work items lane, lane + lanes, ... of `any_hit_packets` (the unused nearest-hit arrays are stand-ins of the
    right types)."""
    org, dirs, tmin, tmax, starts = rays
    occ, n_node, n_tri = out
    n_tasks = (starts.shape[0] - 1 + PACKETS_PER_TASK - 1) // PACKETS_PER_TASK
    for task in range(lane, n_tasks, lanes):
        _trace_task(bvh, root2, org, dirs, tmin, tmax, starts, task, False, occ, n_node, tmax, tmax, tmax, n_node,
                    n_tri, work)


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def _closest_hit_tasks(bvh, root2, rays, lane, lanes, out, work):
    """Work items lane, lane + lanes, ... of `closest_hit_packets`."""
    org, dirs, tmin, tmax, starts = rays
    no_occ, hit, t, b1, b2, n_node, n_tri = out
    n_tasks = (starts.shape[0] - 1 + PACKETS_PER_TASK - 1) // PACKETS_PER_TASK
    for task in range(lane, n_tasks, lanes):
        _trace_task(bvh, root2, org, dirs, tmin, tmax, starts, task, True, no_occ, hit, t, b1, b2, n_node, n_tri,
                    work)


def occluded_segments(bvh, origin, direction, tmax, point, tmin=None):
    """Occlusion of shadow segments (t in (tmin, tmax), tmin 0 by default), traversed in packets of equal
    `point` (the segments of one shading point; contiguous runs are packed, so sort by point): occluded flag,
    node and triangle tests per segment."""
    tmin = np.zeros(len(tmax)) if tmin is None else tmin
    return any_hit_packets(bvh.arrays, origin, direction, tmin, tmax, packet_starts(point))


def nearest_hits(bvh, org, dirs, tmin, tmax):
    """Nearest hits of rays traversed in packets of 64 consecutive rays (order them coherently, as camera
    rays by pixel): as `traversal.closest_hit`."""
    n = len(tmax)
    return closest_hit_packets(bvh.arrays, org, dirs, tmin, tmax, np.append(np.arange(0, n, MAX_PACKET), n))
