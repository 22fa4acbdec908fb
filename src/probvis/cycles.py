"""The processor's cycle counter, read inside kernels to split their time by phase (LLVM's `readcyclecounter`:
`rdtsc` on x86-64, about 30 cycles a read).

A kernel adds the cycles between reads to one slot per phase; the sums over its threads, as shares, split the
kernel's wall time (`split_seconds`). Where the counter does not run (it reads 0 on some processors), every
share is zero and the phases report no time.
"""
import time

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic, overload


@intrinsic
def _read(typingctx):
    def codegen(context, builder, signature, args):
        fn = builder.module.declare_intrinsic("llvm.readcyclecounter", fnty=ir.FunctionType(ir.IntType(64), []))
        return builder.call(fn, [])

    return types.uint64(), codegen


def cycles():
    """The cycle counter now, as a float (differences of a few million cycles stay exact). Called from Python
    (kernels run as Python under NUMBA_DISABLE_JIT, as `precompile` does) it reads the performance counter."""
    return float(time.perf_counter_ns())


@overload(cycles, inline="always")
def _cycles_in_kernels():
    return lambda: np.float64(_read())


def split_seconds(seconds, phase_cycles):
    """`seconds` of a kernel's wall time split in proportion to its phases' cycles (an array)."""
    total = float(np.sum(phase_cycles))
    if total <= 0.0:
        return np.zeros(len(phase_cycles))
    return seconds * np.asarray(phase_cycles, dtype=float) / total
