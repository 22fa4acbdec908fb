"""Packet any-hit traversal against single-ray traversal and brute force."""
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from probvis.accel import any_hit, any_hit_packets, build_bvh, packet_starts

from .test_bvh import brute_closest, random_soup


def test_packet_starts_cut_runs_of_equal_points_into_packets_of_at_most_max_size():
    point = np.array([0, 0, 0, 1, 1, 2, 2, 2, 2, 2, 2, 2, 3])
    np.testing.assert_array_equal(packet_starts(point, 3), [0, 3, 5, 8, 11, 12, 13])
    np.testing.assert_array_equal(packet_starts(np.repeat(np.arange(3), 16)), [0, 16, 32, 48])
    np.testing.assert_array_equal(packet_starts(np.zeros(130, int)), [0, 64, 128, 130])
    np.testing.assert_array_equal(packet_starts(np.array([5])), [0, 1])


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), n_tris=st.integers(1, 300), size=st.floats(0.01, 1.0),
       per_point=st.integers(1, 80), spread=st.floats(0.0, 2.0))
def test_packets_match_single_rays_and_brute_force(seed, n_tris, size, per_point, spread):
    """Segments from shared origins towards scattered targets, some parallel to an axis: the same occlusion
    as brute force, and for every unoccluded segment exactly the tests single-ray traversal makes."""
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
    occ, n_node, n_tri = any_hit_packets(bvh.arrays, org, dirs, tmin, tmax, packet_starts(point))
    s_occ, s_node, s_tri = any_hit(bvh.arrays, org, dirs, tmin, tmax)
    bprim, _ = brute_closest(tris, org, dirs, tmin, tmax)
    np.testing.assert_array_equal(occ, bprim >= 0)
    np.testing.assert_array_equal(occ, s_occ)
    np.testing.assert_array_equal(n_node[~occ], s_node[~occ])
    np.testing.assert_array_equal(n_tri[~occ], s_tri[~occ])
    assert np.all(n_tri[occ] >= 1) and np.all(n_node >= 1)
