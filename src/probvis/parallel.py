"""Parallel loops over blocks of work: the split of an iteration range over the thread budget, and load balance.

Numba splits a `prange` into one contiguous run of iterations per thread; `over_threads` splits a range the
same way for a serial `nogil` kernel run on a pool of that many threads, which Numba compiles without its
parallel-loop passes (the largest kernels compile in a third of the time). Blocks of rays or shading points
in image order are not equally expensive (the top of a Cornell box image is ceiling, the bottom is the
bunny and its shadow), so contiguous runs leave one thread idle while another finishes. Visiting block
`spread(t, n)` in iteration t of either loop gives every thread an even mix of the image instead; results
do not depend on it.
"""
import threading
from concurrent.futures import ThreadPoolExecutor

import numba
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


_pools = {}  # pool size -> its ThreadPoolExecutor, made once
_pools_lock = threading.Lock()


def over_threads(task, n):
    """Run `task(run, first, end)` over contiguous runs (numbered from 0) that split range(n) among
    `numba.get_num_threads()` threads (the render's budget), the calling thread taking run 0; returns when all
    have, raising the first error. `task` calls a `nogil` kernel: the runs execute at once, and no run may start
    parallel work of its own."""
    k = max(1, min(numba.get_num_threads(), n))
    cuts = [n * j // k for j in range(k + 1)]
    with _pools_lock:
        if k > 1 and k not in _pools:
            _pools[k] = ThreadPoolExecutor(k - 1, thread_name_prefix="probvis")
    futures = [_pools[k].submit(task, j, cuts[j], cuts[j + 1]) for j in range(1, k)]
    try:
        task(0, cuts[0], cuts[1])
    finally:
        for f in futures:
            f.result()
