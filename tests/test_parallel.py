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
