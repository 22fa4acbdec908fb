"""Load balance for `prange` loops whose blocks of work differ in cost.

Numba splits a `prange` into one contiguous run of iterations per thread. Blocks of rays or shading points
in image order are not equally expensive (the top of a Cornell box image is ceiling, the bottom is the
bunny and its shadow), so contiguous runs leave one thread idle while another finishes. Visiting block
`spread(t, n)` in iteration t of `prange(n)` gives every thread an even mix of the image instead; results
do not depend on it.
"""
from numba import njit

LANES = 32  # interleaving width: at least the number of threads


@njit(cache=True, inline="always")
def spread(t, n_blocks):
    """Block visited by iteration t of `prange(n_blocks)`, a permutation of 0..n_blocks-1.

    Blocks are laid out in rows of LANES; iterations walk them lane by lane (column-major), so each thread's
    contiguous run of iterations takes whole lanes: every LANES-th block across the image. The first `full`
    lanes hold `rows` blocks, the others one fewer.
    """
    rows = (n_blocks + LANES - 1) // LANES
    full = n_blocks - (rows - 1) * LANES
    if t < full * rows:
        lane, row = t // rows, t % rows
    else:
        u = t - full * rows
        lane, row = full + u // (rows - 1), u % (rows - 1)
    return row * LANES + lane
