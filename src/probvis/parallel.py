"""Parallel loops over blocks of work: the split of an iteration range over the thread budget, and load balance.

Numba splits a `prange` into one contiguous run of iterations per thread; `over_threads` splits a range the
same way for a serial `nogil` kernel run on a pool of that many threads, which Numba compiles without its
parallel-loop passes (the largest kernels compile in a third of the time). Blocks of rays or shading points
in image order are not equally expensive (the top of a Cornell box image is ceiling, the bottom is the
bunny and its shadow), so contiguous runs leave one thread idle while another finishes. Kernels over blocks
therefore visit *lanes*: thread j of k takes blocks j, j + k, j + 2k, ... (`over_lanes` for a serial kernel,
`for lane in prange(lanes)` in a parallel one): every thread an even mix of the image, each in image order, so
a block's rays find the tree nodes and triangles the block before it used still in the cache (an interleave of
single blocks 32 apart made exact renders of city 10-18% slower). Results do not depend on it.
"""
import threading
from concurrent.futures import ThreadPoolExecutor

import numba

_pools = {}  # pool size -> its ThreadPoolExecutor, made once
_pools_lock = threading.Lock()


def lane_count(n):
    """How many threads a range of n blocks is split among: the budget (`numba.get_num_threads()`), at most one
    per block."""
    return max(1, min(numba.get_num_threads(), n))


def over_threads(task, n):
    """Run `task(run, first, end)` over contiguous runs (numbered from 0) that split range(n) among
    `lane_count(n)` threads (the render's budget), the calling thread taking run 0; returns when all have,
    raising the first error. `task` calls a `nogil` kernel: the runs execute at once, and no run may start
    parallel work of its own."""
    k = lane_count(n)
    cuts = [n * j // k for j in range(k + 1)]
    _on_pool(k, lambda j: task(j, cuts[j], cuts[j + 1]))


def over_lanes(task, n):
    """Run `task(lane, lanes)` for each lane of range(n) (`lanes = lane_count(n)`), each on its own thread, the
    calling thread taking lane 0: the task visits blocks lane, lane + lanes, ... (see the module's docstring).
    As `over_threads` otherwise."""
    k = lane_count(n)
    _on_pool(k, lambda j: task(j, k))


def _on_pool(k, call):
    """call(j) for j in 0..k-1 at once: j = 0 on the calling thread, the others on a pool of k - 1 threads."""
    with _pools_lock:
        if k > 1 and k not in _pools:
            _pools[k] = ThreadPoolExecutor(k - 1, thread_name_prefix="probvis")
    futures = [_pools[k].submit(call, j) for j in range(1, k)]
    try:
        call(0)
    finally:
        for f in futures:
            f.result()
