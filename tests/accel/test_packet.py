"""Packet any-hit traversal against single-ray traversal and brute force."""
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from probvis.accel import any_hit, any_hit_packets, build_bvh, occluded_segments

from .test_bvh import brute_closest, random_soup


def runs_of_equal_points(point, max_size=64):
    """Packet starts cutting at every change of `point` and every `max_size` segments: packets whose rays all
    share one origin (the traversal's shortcut for them is tested too)."""
    cut = np.flatnonzero(np.r_[True, point[1:] != point[:-1]])
    starts = np.concatenate([np.arange(a, b, max_size) for a, b in zip(cut, np.r_[cut[1:], len(point)])])
    return np.append(starts, len(point))


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
        occ, n_node, n_tri = any_hit_packets(bvh.arrays, org, dirs, tmin, tmax, runs_of_equal_points(point))
    else:
        occ, n_node, n_tri = occluded_segments(bvh, org, dirs, tmax)
    s_occ, s_node, s_tri = any_hit(bvh.arrays, org, dirs, tmin, tmax)
    bprim, _ = brute_closest(tris, org, dirs, tmin, tmax)
    np.testing.assert_array_equal(occ, bprim >= 0)
    np.testing.assert_array_equal(occ, s_occ)
    np.testing.assert_array_equal(n_node[~occ], s_node[~occ])
    np.testing.assert_array_equal(n_tri[~occ], s_tri[~occ])
    assert np.all(n_tri[occ] >= 1) and np.all(n_node >= 1)
