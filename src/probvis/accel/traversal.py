"""Ray queries against a `BVH`, one ray at a time, each counting its ray-node and ray-triangle tests.

The renderer traces camera rays and shadow segments in packets (`packet`); `closest_hit` and `any_hit` here are
the single-ray reference traversals the packet kernels are tested against (test oracles), and `all_hits`
serves the occlusion map's photon pass. `ray_setup` and `hit_triangle` are the watertight triangle test every
query shares, the candidate-list test (`candidates`) included.

`bvh` is a `BVHArrays`. Rays are (origin, direction, tmin, tmax); a shadow segment from p to q is the
ray (p, q - p) with tmax just below 1. The ray-triangle test is the watertight test of Woop, Benthin and
Wald (JCGT 2013) in double precision: rays through shared edges and vertices never slip between triangles.
"""
import numpy as np
from numba import njit

from ..parallel import over_lanes

CHUNK = 64  # rays per stack allocation in the parallel loops
_BOX_SLACK = 1.0 + 2.0 * 3.0 * 1.1102230246251565e-16  # 1 + 2 gamma(3): conservative slab exit


@njit(cache=True, error_model="numpy", inline="always")
def ray_setup(dx, dy, dz):
    """Per-ray constants of the watertight test: permuted axes and shear."""
    ax, ay, az = abs(dx), abs(dy), abs(dz)
    if ax > ay and ax > az:
        kz = 0
    elif ay > az:
        kz = 1
    else:
        kz = 2
    kx = (kz + 1) % 3
    ky = (kx + 1) % 3
    d = (dx, dy, dz)
    if d[kz] < 0.0:
        kx, ky = ky, kx
    sz = 1.0 / d[kz]
    return kx, ky, kz, d[kx] * sz, d[ky] * sz, sz


@njit(cache=True, error_model="numpy", inline="always")
def slab_setup(dx, dy, dz):
    """Per-ray constants of the slab test: reciprocal direction (inf for a zero component) and, per axis, the
    offset (0 or 3) of the box bound the ray meets first."""
    ix = 1.0 / dx if dx != 0.0 else np.inf
    iy = 1.0 / dy if dy != 0.0 else np.inf
    iz = 1.0 / dz if dz != 0.0 else np.inf
    return ix, iy, iz, 0 if ix >= 0.0 else 3, 0 if iy >= 0.0 else 3, 0 if iz >= 0.0 else 3


@njit(cache=True, error_model="numpy", inline="always")
def hit_triangle(tv, p, o, kx, ky, kz, sx, sy, sz, tmin, tmax):
    """Watertight ray-triangle test of triangle `p` of `tv`; returns (t, b1, b2) with t = inf on a miss."""
    return sheared_hit(tv[p, 0, kx] - o[kx], tv[p, 0, ky] - o[ky], tv[p, 0, kz] - o[kz],
                       tv[p, 1, kx] - o[kx], tv[p, 1, ky] - o[ky], tv[p, 1, kz] - o[kz],
                       tv[p, 2, kx] - o[kx], tv[p, 2, ky] - o[ky], tv[p, 2, kz] - o[kz], sx, sy, sz, tmin, tmax)


@njit(cache=True, error_model="numpy", inline="always")
def triangle_blocks(tv, p, o, kx, ky, kz, sx, sy, sz, tmin, tmax):
    """Whether triangle `p` of `tv` meets the ray in (tmin, tmax): `hit_triangle`'s decision, for any-hit tests."""
    return sheared_blocks(tv[p, 0, kx] - o[kx], tv[p, 0, ky] - o[ky], tv[p, 0, kz] - o[kz],
                          tv[p, 1, kx] - o[kx], tv[p, 1, ky] - o[ky], tv[p, 1, kz] - o[kz],
                          tv[p, 2, kx] - o[kx], tv[p, 2, ky] - o[ky], tv[p, 2, kz] - o[kz], sx, sy, sz, tmin, tmax)


@njit(cache=True, error_model="numpy", inline="always")
def _sheared(ax, ay, az, bx, by, bz, cx, cy, cz, sx, sy, sz, tmin, tmax):
    """The watertight test's edge functions u, v, w, their sum det and the scaled distance tt of a triangle
    whose vertices, minus the ray's origin, are given in the ray's permuted axes (`ray_setup`'s kx, ky, kz); and
    whether the ray meets it in (tmin, tmax): u, v, w of one sign, det nonzero, tt / det inside. The decision is
    a combination of comparisons, not a chain of branches: the tests a shadow segment makes against nearby
    triangles take either side of each comparison unpredictably."""
    ax -= sx * az
    ay -= sy * az
    bx -= sx * bz
    by -= sy * bz
    cx -= sx * cz
    cy -= sy * cz
    u = cx * by - cy * bx
    v = ax * cy - ay * cx
    w = bx * ay - by * ax
    det = u + v + w
    tt = u * (sz * az) + v * (sz * bz) + w * (sz * cz)
    lo, hi = tmin * det, tmax * det
    inside = ((u >= 0.0) & (v >= 0.0) & (w >= 0.0)) | ((u <= 0.0) & (v <= 0.0) & (w <= 0.0))
    between = ((det > 0.0) & (tt > lo) & (tt < hi)) | ((det < 0.0) & (tt < lo) & (tt > hi))
    return inside & between, v, w, det, tt


@njit(cache=True, error_model="numpy", inline="always")
def sheared_hit(ax, ay, az, bx, by, bz, cx, cy, cz, sx, sy, sz, tmin, tmax):
    """The watertight test of a triangle whose vertices, minus the ray's origin, are given in the ray's permuted
    axes (`ray_setup`'s kx, ky, kz): (t, b1, b2), t = inf on a miss."""
    met, v, w, det, tt = _sheared(ax, ay, az, bx, by, bz, cx, cy, cz, sx, sy, sz, tmin, tmax)
    if not met:
        return np.inf, 0.0, 0.0
    inv = 1.0 / det
    return tt * inv, v * inv, w * inv


@njit(cache=True, error_model="numpy", inline="always")
def sheared_blocks(ax, ay, az, bx, by, bz, cx, cy, cz, sx, sy, sz, tmin, tmax):
    """`sheared_hit`'s decision alone: whether the ray meets the triangle in (tmin, tmax)."""
    return _sheared(ax, ay, az, bx, by, bz, cx, cy, cz, sx, sy, sz, tmin, tmax)[0]


@njit(cache=True, error_model="numpy", inline="always")
def hit_box(b, node, off, ox, oy, oz, ix, iy, iz, nx, ny, nz, tmin, tmax):
    """Slab test of the box b[node, off:off + 6] (lo xyz, hi xyz); `nx, ny, nz` are 0 or 3, the offset of
    the bound the ray meets first on each axis. Returns the entry distance, or inf on a miss in [tmin, tmax].

    A zero direction component gives inf * 0 = NaN, which the ordered comparisons ignore; the exit distance
    is widened by 2 gamma(3) so that rounding never culls a box the ray touches.
    """
    t0 = tmin
    tn = (b[node, off + nx] - ox) * ix
    if tn > t0:
        t0 = tn
    tn = (b[node, off + 1 + ny] - oy) * iy
    if tn > t0:
        t0 = tn
    tn = (b[node, off + 2 + nz] - oz) * iz
    if tn > t0:
        t0 = tn
    t1 = np.inf
    tf = (b[node, off + 3 - nx] - ox) * ix
    if tf < t1:
        t1 = tf
    tf = (b[node, off + 4 - ny] - oy) * iy
    if tf < t1:
        t1 = tf
    tf = (b[node, off + 5 - nz] - oz) * iz
    if tf < t1:
        t1 = tf
    t1 *= _BOX_SLACK
    if tmax < t1:
        t1 = tmax
    return t0 if t0 <= t1 else np.inf


@njit(cache=True, error_model="numpy", inline="always")
def trace(cb, ci, root, tv, ox, oy, oz, dx, dy, dz, tmin, tmax, any_hit, stack):
    """Traverse one ray. With `any_hit` stop at the first hit found, else find the nearest.

    Each interior node tests both children's boxes (two node tests) and descends into the nearer hit first.
    Returns (bvh-order primitive or -1, t, b1, b2, node tests, triangle tests); `stack` is caller scratch.
    """
    o = (ox, oy, oz)
    ix, iy, iz, nx, ny, nz = slab_setup(dx, dy, dz)
    kx, ky, kz, sx, sy, sz = ray_setup(dx, dy, dz)
    best, bt, b1, b2 = -1, tmax, 0.0, 0.0
    n_node, n_tri = 1, 0
    if hit_box(root, 0, 0, ox, oy, oz, ix, iy, iz, nx, ny, nz, tmin, bt) == np.inf:
        return best, bt, b1, b2, n_node, n_tri
    sp = 0
    node = 0
    while True:
        cnt = ci[node, 13]
        if cnt == 0:
            n_node += 2
            tl = hit_box(cb, node, 0, ox, oy, oz, ix, iy, iz, nx, ny, nz, tmin, bt)
            tr = hit_box(cb, node, 6, ox, oy, oz, ix, iy, iz, nx, ny, nz, tmin, bt)
            if tl < np.inf:
                if tr < np.inf:
                    if tl <= tr:
                        stack[sp] = ci[node, 12]
                        node = node + 1
                    else:
                        stack[sp] = node + 1
                        node = ci[node, 12]
                    sp += 1
                else:
                    node = node + 1
                continue
            if tr < np.inf:
                node = ci[node, 12]
                continue
        else:
            first = ci[node, 12]
            for p in range(first, first + cnt):
                n_tri += 1
                t, u, v = hit_triangle(tv, p, o, kx, ky, kz, sx, sy, sz, tmin, bt)
                if t < bt:
                    best, bt, b1, b2 = p, t, u, v
                    if any_hit:
                        return best, bt, b1, b2, n_node, n_tri
        if sp == 0:
            break
        sp -= 1
        node = stack[sp]
    return best, bt, b1, b2, n_node, n_tri


@njit(cache=True, error_model="numpy")
def closest_hit(bvh, org, dirs, tmin, tmax):
    """Batched nearest hits, one ray at a time on one thread (a test oracle: as a parallel loop it took
    4 s longer to compile). Returns scene triangle id (-1 on a miss), t, b1, b2, node and triangle tests."""
    cb, ci, root, tv, prim_ids, depth = bvh
    n = org.shape[0]
    prim = np.full(n, -1, np.int32)
    t = np.full(n, np.inf)
    b1 = np.zeros(n)
    b2 = np.zeros(n)
    n_node = np.zeros(n, np.int32)
    n_tri = np.zeros(n, np.int32)
    n_chunks = (n + CHUNK - 1) // CHUNK
    for c in range(n_chunks):
        stack = np.empty(depth, np.int32)
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            p, tt, u, v, a, b = trace(cb, ci, root, tv, org[i, 0], org[i, 1], org[i, 2],
                                      dirs[i, 0], dirs[i, 1], dirs[i, 2], tmin[i], tmax[i], False, stack)
            if p >= 0:
                prim[i] = prim_ids[p]
                t[i], b1[i], b2[i] = tt, u, v
            n_node[i], n_tri[i] = a, b
    return prim, t, b1, b2, n_node, n_tri


@njit(cache=True, error_model="numpy")
def any_hit(bvh, org, dirs, tmin, tmax):
    """Batched occlusion queries, one ray at a time on one thread (a test oracle): occluded flag, node and
    triangle tests per ray."""
    cb, ci, root, tv, prim_ids, depth = bvh
    n = org.shape[0]
    occ = np.zeros(n, np.bool_)
    n_node = np.zeros(n, np.int32)
    n_tri = np.zeros(n, np.int32)
    n_chunks = (n + CHUNK - 1) // CHUNK
    for c in range(n_chunks):
        stack = np.empty(depth, np.int32)
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            p, _, _, _, a, b = trace(cb, ci, root, tv, org[i, 0], org[i, 1], org[i, 2],
                                     dirs[i, 0], dirs[i, 1], dirs[i, 2], tmin[i], tmax[i], True, stack)
            occ[i], n_node[i], n_tri[i] = p >= 0, a, b
    return occ, n_node, n_tri


@njit(cache=True, error_model="numpy", inline="always")
def trace_all(cb, ci, root, tv, ox, oy, oz, dx, dy, dz, tmin, cap, out_t, out_p, stack):
    """Every hit of one ray beyond `tmin`, nearest first, up to `cap` of them (the nearest `cap`).

    Fills `out_t[:count]` and `out_p[:count]` (bvh-order primitives) sorted by distance; returns
    (count, node tests, triangle tests). Once `cap` hits are held, subtrees beyond the farthest are pruned.
    """
    o = (ox, oy, oz)
    ix, iy, iz, nx, ny, nz = slab_setup(dx, dy, dz)
    kx, ky, kz, sx, sy, sz = ray_setup(dx, dy, dz)
    count, n_node, n_tri = 0, 1, 0
    far = np.inf
    if hit_box(root, 0, 0, ox, oy, oz, ix, iy, iz, nx, ny, nz, tmin, far) == np.inf:
        return count, n_node, n_tri
    sp = 0
    node = 0
    while True:
        cnt = ci[node, 13]
        if cnt == 0:
            n_node += 2
            tl = hit_box(cb, node, 0, ox, oy, oz, ix, iy, iz, nx, ny, nz, tmin, far)
            tr = hit_box(cb, node, 6, ox, oy, oz, ix, iy, iz, nx, ny, nz, tmin, far)
            if tl < np.inf:
                if tr < np.inf:
                    stack[sp] = ci[node, 12]
                    sp += 1
                node = node + 1
                continue
            if tr < np.inf:
                node = ci[node, 12]
                continue
        else:
            first = ci[node, 12]
            for p in range(first, first + cnt):
                n_tri += 1
                t, _, _ = hit_triangle(tv, p, o, kx, ky, kz, sx, sy, sz, tmin, far)
                if t < far:
                    # insertion into the sorted hit list, dropping the farthest when full
                    j = count if count < cap else cap - 1
                    while j > 0 and out_t[j - 1] > t:
                        if j < cap:
                            out_t[j] = out_t[j - 1]
                            out_p[j] = out_p[j - 1]
                        j -= 1
                    out_t[j] = t
                    out_p[j] = p
                    if count < cap:
                        count += 1
                    if count == cap:
                        far = out_t[cap - 1]
        if sp == 0:
            break
        sp -= 1
        node = stack[sp]
    return count, n_node, n_tri


def all_hits(bvh, org, dirs, tmin, cap):
    """Batched all-hits queries: per ray the number of hits kept (<= cap), their scene triangle ids and
    distances sorted nearest first, and the node and triangle tests made."""
    n = org.shape[0]
    out = (np.zeros(n, np.int32), np.full((n, cap), -1, np.int32), np.full((n, cap), np.inf), np.zeros(n, np.int32),
           np.zeros(n, np.int32))
    n_chunks = (n + CHUNK - 1) // CHUNK

    def run(lane, lanes):
        scratch = (np.empty(bvh.stack_depth, np.int32), np.empty(cap), np.empty(cap, np.int32))
        _all_hit_chunks(bvh, org, dirs, tmin, cap, lane, lanes, out, scratch)

    over_lanes(run, n_chunks)
    return out


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def _all_hit_chunks(bvh, org, dirs, tmin, cap, lane, lanes, out, scratch):
    """Chunks lane, lane + lanes, ... of `all_hits`' rays, into `out`; `scratch` is this thread's stack and hit
    arrays. Serial and without reference counts, run on the thread budget (`over_lanes`)."""
    cb, ci, root, tv, prim_ids, _ = bvh
    count, tri, dist, n_node, n_tri = out
    stack, ot, op = scratch
    n = org.shape[0]
    n_chunks = (n + CHUNK - 1) // CHUNK
    for c in range(lane, n_chunks, lanes):
        for i in range(c * CHUNK, min(n, (c + 1) * CHUNK)):
            k, a, b = trace_all(cb, ci, root, tv, org[i, 0], org[i, 1], org[i, 2], dirs[i, 0], dirs[i, 1],
                                dirs[i, 2], tmin[i], cap, ot, op, stack)
            count[i], n_node[i], n_tri[i] = k, a, b
            for j in range(k):
                tri[i, j] = prim_ids[op[j]]
                dist[i, j] = ot[j]
