"""The BVH against brute force: closest hits, any-hit segments, test counts, watertightness."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numba import njit

from probvis.accel import all_hits, any_hit, build_bvh, closest_hit
from probvis.accel.traversal import hit_triangle, ray_setup


@njit(cache=True)  # serial: a parallel loop compiles for seconds longer than the rays take
def brute_closest(tris, org, dirs, tmin, tmax):
    n = org.shape[0]
    best_t = tmax.copy()
    best = np.full(n, -1)
    for i in range(n):
        kx, ky, kz, sx, sy, sz = ray_setup(dirs[i, 0], dirs[i, 1], dirs[i, 2])
        o = (org[i, 0], org[i, 1], org[i, 2])
        for p in range(tris.shape[0]):
            t, _, _ = hit_triangle(tris, p, o, kx, ky, kz, sx, sy, sz, tmin[i], best_t[i])
            if t < best_t[i]:
                best_t[i], best[i] = t, p
    return best, best_t


def random_soup(rng, n, spread=1.0, size=0.3):
    centres = rng.uniform(-spread, spread, (n, 1, 3))
    return centres + rng.normal(scale=size, size=(n, 3, 3))


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), n_tris=st.integers(1, 400), size=st.floats(0.01, 1.0))
def test_closest_and_any_hit_match_brute_force(seed, n_tris, size):
    rng = np.random.default_rng(seed)
    tris = random_soup(rng, n_tris, size=size)
    bvh = build_bvh(tris)
    n = 300
    org = rng.uniform(-1.5, 1.5, (n, 3))
    dirs = rng.normal(size=(n, 3))
    tmin = np.zeros(n)
    tmax = rng.choice([np.inf, 1.0, 0.3], size=n)
    prim, t, _, _, n_node, n_tri = closest_hit(bvh.arrays, org, dirs, tmin, tmax)
    bprim, bt = brute_closest(tris, org, dirs, tmin, tmax)
    hit = bprim >= 0
    np.testing.assert_array_equal(prim >= 0, hit)
    np.testing.assert_allclose(t[hit], bt[hit], rtol=1e-12)
    # the same triangle, unless two triangles are hit at the same distance
    assert np.all((prim[hit] == bprim[hit]) | np.isclose(t[hit], bt[hit], rtol=1e-12))
    occ, a_node, a_tri = any_hit(bvh.arrays, org, dirs, tmin, tmax)
    np.testing.assert_array_equal(occ, hit)
    assert np.all(n_node >= 1) and np.all(a_node >= 1)
    assert np.all(n_tri <= n_tris) and np.all(a_tri <= n_tri)
    assert np.all(n_tri[hit] >= 1)


@njit(cache=True)
def brute_all(tris, o, d):
    kx, ky, kz, sx, sy, sz = ray_setup(d[0], d[1], d[2])
    ts = []
    for p in range(tris.shape[0]):
        t, _, _ = hit_triangle(tris, p, (o[0], o[1], o[2]), kx, ky, kz, sx, sy, sz, 0.0, np.inf)
        if t < np.inf:
            ts.append(t)
    return np.sort(np.array(ts + [0.0])[:-1])


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**31), n_tris=st.integers(1, 300), cap=st.integers(1, 12))
def test_all_hits_match_brute_force(seed, n_tris, cap):
    rng = np.random.default_rng(seed)
    tris = random_soup(rng, n_tris, size=0.5)
    bvh = build_bvh(tris)
    n = 100
    org = rng.uniform(-1.5, 1.5, (n, 3))
    dirs = rng.normal(size=(n, 3))
    count, tri, dist, _, n_tri = all_hits(bvh.arrays, org, dirs, np.zeros(n), cap)
    for i in range(n):
        expect = brute_all(tris, org[i], dirs[i])[:cap]
        assert count[i] == len(expect)
        np.testing.assert_allclose(dist[i, :count[i]], expect, rtol=1e-12)
        assert np.all(tri[i, count[i]:] == -1)
        for j in range(count[i]):  # each reported triangle is really hit at the reported distance
            kx, ky, kz, sx, sy, sz = ray_setup(*dirs[i])
            t, _, _ = hit_triangle(tris, tri[i, j], tuple(org[i]), kx, ky, kz, sx, sy, sz, 0.0, np.inf)
            assert t == dist[i, j]
    assert np.all(n_tri <= n_tris)


def test_bvh_partitions_all_triangles_and_stays_shallow():
    rng = np.random.default_rng(3)
    tris = random_soup(rng, 20000, spread=10.0, size=0.05)
    bvh = build_bvh(tris)
    assert sorted(bvh.prim_ids.tolist()) == list(range(len(tris)))
    np.testing.assert_array_equal(bvh.tri_v, tris[bvh.prim_ids])
    s = bvh.stats()
    assert s["leaves"] * 1 <= len(tris) and s["max_leaf_size"] <= 8
    assert s["max_depth"] < 40
    leaves = bvh.node_count > 0
    assert bvh.node_count[leaves].sum() == len(tris)


def test_identical_triangles_do_not_break_the_build():
    tri = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    bvh = build_bvh(np.repeat(tri, 100, axis=0))
    occ, _, n_tri = any_hit(bvh.arrays, np.array([[0.2, 0.2, 1.0]]), np.array([[0.0, 0.0, -2.0]]),
                            np.zeros(1), np.ones(1))
    assert occ[0] and n_tri[0] == 1  # early exit on the first hit


def fan(k=12):
    """A fan of k triangles around the origin in the z = 0 plane, and points on its shared edges and centre."""
    ang = np.linspace(0, 2 * np.pi, k, endpoint=False)
    ring = np.column_stack([np.cos(ang), np.sin(ang), np.zeros(k)])
    tris = np.stack([np.zeros((k, 3)), ring, np.roll(ring, -1, axis=0)], axis=1)
    return tris, np.vstack([[0.0, 0.0, 0.0], ring * 0.5, ring * 0.999])


def test_rays_through_shared_edges_and_vertices_never_leak():
    """A fan of triangles around a vertex, hit exactly on its shared edges and at the centre."""
    tris, targets = fan()
    bvh = build_bvh(tris)
    org = targets + np.array([0.3, -0.2, 1.0])
    dirs = targets - org
    prim, t, _, _, _, _ = closest_hit(bvh.arrays, org, dirs, np.zeros(len(org)), np.full(len(org), np.inf))
    assert np.all(prim >= 0)
    np.testing.assert_allclose(t, 1.0, rtol=1e-12)


def test_segment_stops_before_tmax():
    tri = np.array([[[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]]])
    bvh = build_bvh(tri)
    org = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    dirs = np.array([[0.0, 0.0, -2.0], [0.0, 0.0, -2.0]])
    occ, _, _ = any_hit(bvh.arrays, org, dirs, np.zeros(2), np.array([0.49, 0.51]))
    assert occ.tolist() == [False, True]


def test_sah_separates_clusters_that_a_median_split_would_cut():
    """900 triangles near x = -5 and 100 near x = +5: the surface-area heuristic puts the split between the
    clusters; a median-by-count split would cut the large cluster."""
    rng = np.random.default_rng(0)
    big = random_soup(rng, 900, spread=0.5, size=0.01) + np.array([-5.0, 0, 0])
    small = random_soup(rng, 100, spread=0.5, size=0.01) + np.array([5.0, 0, 0])
    bvh = build_bvh(np.concatenate([big, small]))
    left = bvh.bounds[1]
    right = bvh.bounds[bvh.node_index[0]]
    lo, hi = sorted([left, right], key=lambda b: b[0])
    assert lo[3] < -4 and hi[0] > 4  # each child holds exactly one cluster


def test_parallel_build_gives_the_single_threaded_tree():
    """Subtrees below the top levels are built concurrently and spliced in: the same arrays as one thread."""
    import numba

    from probvis.accel.sah_build import PARALLEL_MIN_TRIANGLES

    rng = np.random.default_rng(5)
    tris = random_soup(rng, PARALLEL_MIN_TRIANGLES + 5000, size=0.02)
    tris[:3000] = tris[0]  # a clump of identical triangles (count splits) inside the parallel part
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = build_bvh(tris)
    finally:
        numba.set_num_threads(threads)
    if threads < 2:
        pytest.skip("one thread: nothing is built concurrently")
    many = build_bvh(tris)
    for a, b in ((one.bounds, many.bounds), (one.node_index, many.node_index), (one.node_count, many.node_count),
                 (one.prim_ids, many.prim_ids), (one.packed, many.packed)):
        np.testing.assert_array_equal(a, b)
    assert one.max_depth == many.max_depth


def _chained_decision(ax, ay, az, bx, by, bz, cx, cy, cz, sx, sy, sz, tmin, tmax):
    """The watertight test as Woop, Benthin and Wald write it, branch after branch, and the any-hit decision
    callers took from it (a finite distance): the reference of the branch-free `sheared_blocks`."""
    ax, ay, bx, by, cx, cy = ax - sx * az, ay - sy * az, bx - sx * bz, by - sy * bz, cx - sx * cz, cy - sy * cz
    u, v, w = cx * by - cy * bx, ax * cy - ay * cx, bx * ay - by * ax
    if (u < 0.0 or v < 0.0 or w < 0.0) and (u > 0.0 or v > 0.0 or w > 0.0):
        return False
    det = u + v + w
    if det == 0.0:
        return False
    tt = u * (sz * az) + v * (sz * bz) + w * (sz * cz)
    if det < 0.0:
        if tt >= tmin * det or tt <= tmax * det:
            return False
    elif tt <= tmin * det or tt >= tmax * det:
        return False
    return tt / det < np.inf


def test_the_branch_free_decision_is_the_chained_tests():
    """On vertices shared exactly (edge functions of 0), degenerate triangles (det 0), distances at tmin and
    tmax, either winding, NaN and infinite coordinates: `sheared_blocks` decides as the chained test and as
    `sheared_hit`."""
    from probvis.accel.traversal import sheared_blocks, sheared_hit
    rng = np.random.default_rng(7)
    grid = np.array([-1.0, -0.5, 0.0, 0.5, 1.0])  # coordinates on a coarse grid: exact zeros and ties
    rows = [rng.choice(grid, 12) for _ in range(4000)] + [rng.normal(size=12) for _ in range(4000)]
    rows += [np.r_[rng.choice(grid, 9), [0.0, 0.0, 1.0]] for _ in range(2000)]  # no shear: exact edge hits
    special = [np.nan, np.inf, -np.inf]
    for _ in range(500):
        r = rng.normal(size=12)
        r[rng.integers(12)] = special[rng.integers(3)]
        rows.append(r)
    decided = 0
    for r in rows:
        for tmin, tmax in ((0.0, 1.0), (0.0, 0.5), (0.5, 1.0), (0.0, np.inf)):
            with np.errstate(all="ignore"):
                expected = _chained_decision(*r, tmin, tmax)
            assert sheared_blocks(*r, tmin, tmax) == expected, (r, tmin, tmax)
            assert (sheared_hit(*r, tmin, tmax)[0] < np.inf) == expected, (r, tmin, tmax)
            decided += expected
    assert 1000 < decided < 0.9 * 4 * len(rows)  # both outcomes well represented


def test_any_hit_segments_through_shared_edges_never_leak():
    """The any-hit tests (`triangle_blocks`, `sheared_blocks`) of the BVH's packets and of candidate lists on the
    fan of triangles, hit exactly on its shared edges and at the centre: every segment that reaches the fan is
    blocked, none that stops short."""
    from probvis.accel import occluded_segments, visibility_from_lists
    tris, targets = fan()
    bvh = build_bvh(tris)
    k, n = len(tris), len(targets)
    org = targets + np.array([0.3, -0.2, 1.0])
    dirs = 2.0 * (targets - org)
    lo, hi, cand = np.zeros(n, np.int64), np.full(n, k, np.int64), np.arange(k, dtype=np.int32)
    for tmax, blocked in ((0.75, True), (0.4999, False)):
        tm = np.full(n, tmax)
        occ, _, _ = occluded_segments(bvh, org, dirs, tm, np.zeros(n, np.int64))
        assert (occ == blocked).all()
        vis, _, _ = visibility_from_lists(tris, np.zeros(k, np.int8), np.tile([0.0, 0.0, 1.0], (k, 1)), org, dirs, tm,
                                          lo, hi, cand)
        assert (vis == (0.0 if blocked else 1.0)).all()
