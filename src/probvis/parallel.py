"""Load balance for `prange` loops whose blocks of work differ in cost.

Numba splits a `prange` into one contiguous run of iterations per thread. Blocks of rays or shading points
in image order are not equally expensive (the top of a Cornell box image is ceiling, the bottom is the
bunny and its shadow), so contiguous runs leave one thread idle while another finishes. Iterating with
`spread` gives every thread an even mix of the image instead; results do not depend on it.
"""
from numba import njit

LANES = 32  # interleaving width: at least the number of threads


@njit(cache=True, inline="always")
def spread_iterations(n_blocks):
    """Iterations of the `prange` that visits blocks 0..n_blocks-1 through `spread`."""
    return LANES * ((n_blocks + LANES - 1) // LANES)


@njit(cache=True, inline="always")
def spread(t, n_blocks):
    """Block visited by iteration t of `prange(spread_iterations(n_blocks))`, or -1 for none: iteration
    t = lane * rows + row visits block row * LANES + lane, so each thread's contiguous run of iterations
    takes whole lanes, every LANES-th block across the image."""
    rows = (n_blocks + LANES - 1) // LANES
    lane = t // rows
    block = (t - lane * rows) * LANES + lane
    return block if block < n_blocks else -1
