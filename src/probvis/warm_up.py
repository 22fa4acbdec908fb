"""The warm-up: before a process's first render with an estimator, its options and a scene of that size, the
integrator's warm-up renders (`integrator.warm_up_render`, on a 4x4 scene of its own) run every kernel the render
will, so that Numba compiles them (a first run) or loads them from its cache outside the timed render; on a cold
cache with more than one thread, child processes compile them in parallel first (`precompile`)."""
import sys
import time
from contextlib import nullcontext
from pathlib import Path

import numba
from numba.core import event

from . import precompile
from .errors import is_builtin

COMPILE_TIME = "about half a minute"  # a first run's compilation on 2 cores (17-26 s exact, 33-36 s probvis)

_warmed = set()
_failed = set()  # plug-ins whose warm-up raised: not warm (their first render compiles), not tried again


def largest_mesh(scene):
    """Triangles of the scene's largest shape that does not emit: whether heavy meshes' kernels may run."""
    return max((s.n_triangles for s in scene.shapes if s.emitter < 0), default=0)


def _key(cls, options, largest):
    """What a warm-up ran: the estimator and its warm-up renders' options (scenes that warm up alike share it)."""
    try:
        runs = cls.warm_ups(options, largest)
    except Exception:  # noqa: BLE001 - a plug-in's warm_ups that fails: keyed by what it was given
        runs = (sorted(options.items()), largest)
    return cls, repr(runs)


def is_warm(cls, options, largest):
    """Whether this process warmed `cls` up for `options` and a scene whose largest mesh has `largest` triangles."""
    return _key(cls, options, largest) in _warmed


def cold_cache():
    """Whether Numba's on-disk cache lacks the kernels (a first run, or a changed probvis); under
    NUMBA_DISABLE_JIT the kernels are plain functions: nothing to compile, no cache."""
    from .fused_exact import _shade_blocks

    index = getattr(getattr(getattr(_shade_blocks, "_cache", None), "_cache_file", None), "_index_path", None)
    return index is not None and not Path(index).exists()


class CompileProgress(event.Listener):
    """A progress bar over the kernels compiled in this process (Numba's compile events) or, through `bar`,
    by `precompile`."""

    def __init__(self):
        from tqdm import tqdm
        self.bar = tqdm(desc="compiling kernels", unit=" kernels", leave=False)
        self.listener = event.install_listener("numba:compile", self)

    def on_start(self, ev):
        pass

    def on_end(self, ev):
        self.bar.update(1)

    def __enter__(self):
        self.listener.__enter__()
        return self

    def __exit__(self, *exc):
        self.listener.__exit__(*exc)
        self.bar.close()


def ensure_warm(warm_up_render, cls, options, largest, progress):
    """Run `warm_up_render(cls, options, largest)` (see the module docstring) unless this process did; returns
    seconds. A plug-in whose warm-up fails (its own checks refuse that scene) is not warmed up: its render says
    why."""
    key = _key(cls, options, largest)
    if key in _warmed or key in _failed:
        return 0.0
    t0 = time.perf_counter()
    cold = progress and cold_cache()
    if cold:
        print(f"probvis: compiling kernels (first run only: {COMPILE_TIME} on 2 cores)", file=sys.stderr, flush=True)
    threads = numba.get_num_threads()
    with CompileProgress() if cold and sys.stderr.isatty() else nullcontext() as shown:
        if cold and threads > 1:
            precompile.fill_cache([(warm_up_render, (cls, options, largest))], threads, shown.bar if shown else None)
        numba.set_num_threads(1)  # compile in this thread: a pool thread's compile would hold an interrupt's exit
        try:
            warm_up_render(cls, options, largest)
        except Exception:  # noqa: BLE001 - the warm-up only saves time; a built-in's failure is a bug
            if is_builtin(cls):
                raise
            _failed.add(key)
            return time.perf_counter() - t0
        finally:
            numba.set_num_threads(threads)
    _warmed.add(key)
    return time.perf_counter() - t0
