"""Packet any-hit traversal against single-ray traversal and brute force."""
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from probvis.accel import any_hit, any_hit_packets, build_bvh, closest_hit, closest_hit_packets, nearest_hits, \
    occluded_segments, packet_starts

from .test_bvh import brute_closest, random_soup


def test_packet_starts_cut_runs_of_equal_points_into_packets_of_at_most_max_size():
    point = np.array([0, 0, 0, 1, 1, 2, 2, 2, 2, 2, 2, 2, 3])
    np.testing.assert_array_equal(packet_starts(point, 3), [0, 3, 5, 8, 11, 12, 13])
    np.testing.assert_array_equal(packet_starts(np.repeat(np.arange(3), 16)), [0, 16, 32, 48])
    np.testing.assert_array_equal(packet_starts(np.zeros(70, int)), [0, 32, 64, 70])  # SHADOW_PACKET
    np.testing.assert_array_equal(packet_starts(np.array([5])), [0, 1])


def runs_of_64(n):
    """Packets of 64 consecutive rays, whatever their origins (the traversal's general case)."""
    return np.append(np.arange(0, n, 64), n)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), n_tris=st.integers(1, 300), size=st.floats(0.01, 1.0),
       per_point=st.integers(1, 80), spread=st.floats(0.0, 2.0), by_point=st.booleans())
def test_packets_match_single_rays_and_brute_force(seed, n_tris, size, per_point, spread, by_point):
    """Segments from shared origins towards scattered targets, some parallel to an axis, in packets of one
    origin or of 64 consecutive segments: the same occlusion as brute force, and for every unoccluded segment
    exactly the tests single-ray traversal makes."""
    rng = np.random.default_rng(seed)
    tris = random_soup(rng, n_tris, size=size)
    bvh = build_bvh(tris)
    n_points = 12
    point = np.repeat(np.arange(n_points), per_point)
    org = rng.uniform(-1.5, 1.5, (n_points, 3))[point]
    target = org + rng.normal(size=(len(point), 3)) * spread + rng.normal(size=3)
    dirs = target - org
    dirs[::7, rng.integers(3)] = 0.0  # axis-parallel segments
    tmin = np.zeros(len(point))
    tmax = rng.choice([1.0, 0.5, np.inf], size=len(point))
    if by_point:
        occ, n_node, n_tri = occluded_segments(bvh, org, dirs, tmax, point)
    else:
        occ, n_node, n_tri = any_hit_packets(bvh.arrays, org, dirs, tmin, tmax, runs_of_64(len(point)))
    s_occ, s_node, s_tri = any_hit(bvh.arrays, org, dirs, tmin, tmax)
    bprim, _ = brute_closest(tris, org, dirs, tmin, tmax)
    np.testing.assert_array_equal(occ, bprim >= 0)
    np.testing.assert_array_equal(occ, s_occ)
    np.testing.assert_array_equal(n_node[~occ], s_node[~occ])
    np.testing.assert_array_equal(n_tri[~occ], s_tri[~occ])
    assert np.all(n_tri[occ] >= 1) and np.all(n_node >= 1)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), n_tris=st.integers(1, 300), size=st.floats(0.01, 1.0),
       per_point=st.integers(1, 80), spread=st.floats(0.0, 2.0), by_point=st.booleans())
def test_nearest_hit_packets_match_single_rays_and_brute_force(seed, n_tris, size, per_point, spread, by_point):
    """Rays from shared origins (as camera rays from a pinhole), some parallel to an axis: the nearest hit of
    brute force and of single-ray traversal (t, triangle up to ties, barycentrics), with at least one node
    test per ray and no more triangle tests than triangles."""
    rng = np.random.default_rng(seed)
    tris = random_soup(rng, n_tris, size=size)
    bvh = build_bvh(tris)
    point = np.repeat(np.arange(12), per_point)
    org = rng.uniform(-1.5, 1.5, (12, 3))[point]
    dirs = rng.normal(size=(len(point), 3)) * spread + rng.normal(size=3)
    dirs[::5, rng.integers(3)] = 0.0
    tmin = np.zeros(len(point))
    tmax = rng.choice([np.inf, 1.0, 0.3], size=len(point))
    if by_point:
        prim, t, b1, b2, n_node, n_tri = closest_hit_packets(bvh.arrays, org, dirs, tmin, tmax, packet_starts(point))
    else:
        prim, t, b1, b2, n_node, n_tri = nearest_hits(bvh, org, dirs, tmin, tmax)
    s_prim, s_t, s_b1, s_b2, _, _ = closest_hit(bvh.arrays, org, dirs, tmin, tmax)
    bprim, bt = brute_closest(tris, org, dirs, tmin, tmax)
    hit = bprim >= 0
    np.testing.assert_array_equal(prim >= 0, hit)
    np.testing.assert_array_equal(t[hit], bt[hit])
    assert np.all(np.isinf(t[~hit]))
    same = prim == s_prim  # the same triangle unless two are hit at the same distance
    assert np.all(same | (t == s_t))
    np.testing.assert_array_equal(b1[same], s_b1[same])
    np.testing.assert_array_equal(b2[same], s_b2[same])
    assert np.all(n_node >= 1) and np.all(n_tri <= n_tris) and np.all(n_tri[hit] >= 1)
