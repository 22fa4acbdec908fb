"""`spread` visits every block exactly once and gives each thread's contiguous run an even mix of blocks."""
import numpy as np
import pytest

from probvis.parallel import LANES, spread


@pytest.mark.parametrize("n_blocks", [0, 1, 5, LANES - 1, LANES, LANES + 1, 2 * LANES + 7, 1000])
def test_every_block_once(n_blocks):
    visited = [spread(t, n_blocks) for t in range(n_blocks)]
    assert sorted(visited) == list(range(n_blocks))


def test_contiguous_halves_mix_the_image():
    n = 1000
    visited = np.array([spread(t, n) for t in range(n)])
    for half in (visited[:n // 2], visited[n // 2:]):
        assert half.min() < n / LANES and half.max() > n - n / LANES  # spans the image, not one half of it
        assert abs(np.mean(half) - (n - 1) / 2) < n / LANES  # an even mix, not the cheap or dear end


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
