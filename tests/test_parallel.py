"""`spread` visits every block exactly once and gives each thread's contiguous run an even mix of blocks."""
import numpy as np
import pytest

from probvis.parallel import LANES, spread, spread_iterations


@pytest.mark.parametrize("n_blocks", [0, 1, 5, LANES - 1, LANES, LANES + 1, 1000])
def test_every_block_once(n_blocks):
    visited = [spread(t, n_blocks) for t in range(spread_iterations(n_blocks))]
    assert sorted(b for b in visited if b >= 0) == list(range(n_blocks))


def test_contiguous_halves_mix_the_image():
    n = 1000
    visited = np.array([spread(t, n) for t in range(spread_iterations(n))])
    first, second = visited[:len(visited) // 2], visited[len(visited) // 2:]
    for half in (first[first >= 0], second[second >= 0]):
        assert abs(len(half) - n / 2) <= LANES
        assert half.min() < n / LANES and half.max() > n - n / LANES  # spans the image, not one half of it
