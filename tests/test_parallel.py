"""Lanes visit every block exactly once, each an even mix of the image in image order; `over_threads` splits a
range into contiguous runs."""
import numba
import numpy as np
import pytest

from probvis.parallel import lane_count, over_lanes


def _lanes(threads, n):
    """The blocks each lane of `over_lanes` visits (as its kernels loop: range(lane, n, lanes))."""
    seen = {}
    before, threads = numba.get_num_threads(), min(threads, numba.config.NUMBA_NUM_THREADS)
    numba.set_num_threads(threads)
    try:
        over_lanes(lambda lane, lanes: seen.setdefault(lane, list(range(lane, n, lanes))), n)
        assert len(seen) == lane_count(n) == max(1, min(threads, n))
    finally:
        numba.set_num_threads(before)
    return [seen[j] for j in sorted(seen)]


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("n", [0, 1, 3, 1000])
def test_lanes_visit_every_block_once_each_in_image_order(threads, n):
    lanes = _lanes(threads, n)
    assert sorted(b for lane in lanes for b in lane) == list(range(n))
    assert all(lane == sorted(lane) for lane in lanes)


def test_each_lane_is_an_even_mix_of_the_image():
    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("needs two threads")
    n = 1000
    for lane in _lanes(2, n):
        assert min(lane) < 2 and max(lane) > n - 3  # spans the image, not one half of it
        assert abs(np.mean(lane) - (n - 1) / 2) < 1  # an even mix, not the cheap or dear end


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("n", [0, 1, 3, 1000])
def test_over_threads_covers_the_range_once(threads, n):
    import numba

    from probvis.parallel import over_threads
    runs = []
    before, threads = numba.get_num_threads(), min(threads, numba.config.NUMBA_NUM_THREADS)
    numba.set_num_threads(threads)
    try:
        over_threads(lambda _, first, end: runs.append((first, end)), n)
    finally:
        numba.set_num_threads(before)
    runs.sort()
    assert runs[0][0] == 0 and runs[-1][1] == n
    assert all(a[1] == b[0] for a, b in zip(runs, runs[1:]))  # contiguous, no gap, no overlap
    assert len(runs) == max(1, min(threads, n))  # one run per thread of the budget


def test_over_threads_raises_a_runs_error_after_all_runs_end():
    import numba

    from probvis.parallel import over_threads
    ended = []

    def task(_, first, end):
        if first > 0:
            raise ValueError("second run")
        ended.append(first)

    before = numba.get_num_threads()
    numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
    try:
        if numba.get_num_threads() < 2:
            pytest.skip("needs two threads")
        with pytest.raises(ValueError, match="second run"):
            over_threads(task, 10)
    finally:
        numba.set_num_threads(before)
    assert ended == [0]
