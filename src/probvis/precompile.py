"""A first run's kernels compiled in parallel: child processes fill Numba's on-disk cache.

Numba compiles a kernel in the process that first calls it, one kernel at a time, so a first run on two cores
compiled for a minute on one of them. The kernels a render calls from Python, and the types of their
arguments, are those of its warm-up render (`integrator.warm_up_render`, a 4x4 scene); `fill_cache`

1. finds them by running that render in a child process as plain Python (`NUMBA_DISABLE_JIT=1`, about a
   second), recording each kernel called from Python with the Numba types of its arguments, as the dispatcher
   types them (`typeof`; parameters left to their defaults are `Omitted`);
2. compiles them in `workers` child processes with `Dispatcher.compile`, which writes the cache as a first
   call would, the largest first (by the bytecode of the functions each call ran) and each to the next free
   worker;

after which the warm-up in this process loads every kernel from the cache. Kernels that only other kernels
call compile inside their callers (there, constant arguments are typed as literals, which Python values never
are). Nothing here is an error: whatever fails is compiled by the warm-up in this process, as without it.
"""
import base64
import importlib
import os
import pickle
import selectors
import signal
import subprocess
import sys
from pathlib import Path

DISCOVERY_SECONDS = 120  # the plain-Python warm-up takes about a second
JOB_SECONDS = 600  # the largest kernel compiles in under a minute
PARENT = "PROBVIS_PRECOMPILE_PARENT"  # the environment variable that gives a child its parent's process id


def fill_cache(calls, workers, bar=None):
    """Compile the kernels that `calls`, a list of (function, arguments) such as
    `[(integrator.warm_up_render, (cls, options))]`, run, in `workers` processes; returns how many were compiled
    (0 if that could not be done). `bar` (a tqdm bar or None) counts the kernels."""
    jobs = _discover(calls)
    if not jobs:
        return 0
    if bar is not None:
        bar.reset(total=len(jobs))
    return _compile(jobs, min(workers, len(jobs)), bar)


def _child(role, extra_env):
    """A child process running this module's `role`, with this process's probvis first on its path and not the
    working folder (`-P`: a `numba.py` there is not imported), its output to pipes (its errors, if any, are not
    shown: the warm-up reports them)."""
    env = {**os.environ, **extra_env, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", PARENT: str(os.getpid()),
           "OPENBLAS_NUM_THREADS": "1", "PYTHONWARNINGS": "ignore",
           "PYTHONPATH": os.pathsep.join(p for p in [str(Path(__file__).resolve().parent.parent),
                                                     *os.environ.get("PYTHONPATH", "").split(os.pathsep)] if p)}
    return subprocess.Popen([sys.executable, "-P", "-m", "probvis.precompile", role], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=env)


def _discover(calls):
    """The kernels (module, name, argument types, weight) that `calls` run from Python, the heaviest first; [] if
    the calls cannot reach the child (a function or class defined inside a function) or fail there."""
    try:
        payload = pickle.dumps(calls)
    except (pickle.PicklingError, AttributeError, TypeError):
        return []
    proc = _child("discover", {"NUMBA_DISABLE_JIT": "1"})
    interrupted = True
    try:
        out, _ = proc.communicate(payload, timeout=DISCOVERY_SECONDS)
        interrupted = False
    except subprocess.TimeoutExpired:
        return []
    finally:
        _stop(proc, interrupted)
    if proc.returncode != 0:
        return []
    try:
        return pickle.loads(out)
    except Exception:  # noqa: BLE001 - a child that printed something else: compile in this process instead
        return []


def _compile(jobs, workers, bar):
    """Hand `jobs` to `workers` child processes, one at a time to whichever is free; returns how many
    compiled."""
    procs = [_child("compile", {}) for _ in range(workers)]
    todo, done, interrupted, stuck = list(jobs), 0, True, False
    sel = selectors.DefaultSelector()
    try:
        for proc in procs:
            _send(proc, todo, sel)
        while sel.get_map():
            ready = sel.select(timeout=JOB_SECONDS)
            if not ready:  # a worker is stuck: stop them all, the warm-up compiles what is left
                stuck = True
                break
            for key, _ in ready:
                proc = key.data
                reply = proc.stdout.readline()
                sel.unregister(proc.stdout)
                if reply != b"ok\n":  # a worker that failed or died gets no more work
                    continue
                done += 1
                if bar is not None:
                    bar.update(1)
                _send(proc, todo, sel)
        interrupted = stuck
    finally:
        sel.close()
        for proc in procs:
            _stop(proc, interrupted)
    return done


def _send(proc, todo, sel):
    """The next job to `proc`, or the end of its input if none is left."""
    try:
        if todo:
            proc.stdin.write(base64.b64encode(pickle.dumps(todo.pop(0))) + b"\n")
            proc.stdin.flush()
            sel.register(proc.stdout, selectors.EVENT_READ, proc)
        else:
            proc.stdin.close()
    except OSError:  # it died: its job is compiled by the warm-up
        pass


def _stop(proc, at_once):
    """End a child: let it finish (its input closed) unless `at_once` (an interrupt), killing it if it does not
    within seconds."""
    if proc.stdin and not proc.stdin.closed:
        try:
            proc.stdin.close()
        except OSError:
            pass
    if at_once:
        proc.kill()
    try:
        proc.wait(timeout=5)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


class _Recorder:
    """A stand-in for `numba.njit` under NUMBA_DISABLE_JIT: the decorated functions run as Python, and each call
    made from Python (not from another kernel) is recorded with its argument types once per signature, with
    the bytecode size of the kernels that call ran."""

    def __init__(self):
        self.calls, self.depth, self.ran = {}, 0, set()

    def njit(self, *args, **_):
        if args and callable(args[0]):
            return self._wrap(args[0])
        return self._wrap

    def _wrap(self, func):
        import functools
        import inspect

        from numba import typeof, types
        from numba.core.typing.typeof import Purpose

        sig = inspect.signature(func)

        @functools.wraps(func)
        def call(*args, **kwargs):
            if self.depth == 0:
                bound = sig.bind(*args, **kwargs)
                argtypes = tuple(typeof(bound.arguments[n], Purpose.argument) if n in bound.arguments
                                 else types.Omitted(p.default) for n, p in sig.parameters.items())
                key = (func.__module__, func.__qualname__, argtypes)
                self.ran = set()
            self.ran.add(func.__code__)
            self.depth += 1
            try:
                return func(*args, **kwargs)
            finally:
                self.depth -= 1
                if self.depth == 0:
                    weight = sum(len(c.co_code) for c in self.ran)
                    self.calls[key] = max(weight, self.calls.get(key, 0))

        call.py_func = func
        return call


def _discover_main():
    """Child: read the calls, run them as Python, print the kernels they called from Python."""
    import numba

    recorder = _Recorder()
    numba.njit = recorder.njit  # before the calls' modules (and their kernels) are imported, by unpickling them
    for func, args in pickle.load(sys.stdin.buffer):
        func(*args)
    jobs = sorted(((m, n, t, w) for (m, n, t), w in recorder.calls.items()), key=lambda j: -j[3])
    sys.stdout.buffer.write(pickle.dumps(jobs))


def _compile_main():
    """Child: compile each job read from the input (one per line), answering "ok" or "failed" for each."""

    for line in sys.stdin.buffer:
        module, name, argtypes, _ = pickle.loads(base64.b64decode(line))
        try:
            kernel = importlib.import_module(module)
            for part in name.split("."):
                kernel = getattr(kernel, part)
            kernel.compile(argtypes)
            reply = b"ok\n"
        except Exception:  # noqa: BLE001 - the warm-up compiles (and reports) it
            reply = b"failed\n"
        sys.stdout.buffer.write(reply)
        sys.stdout.buffer.flush()


def _die_with_parent():
    """Ask Linux to kill this child when the process that started it dies, however it dies (a SIGQUIT or SIGUSR1
    has no handler there: the children went on compiling under init); elsewhere the parent's clean-up alone."""
    import ctypes

    try:
        ctypes.CDLL(None).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() != int(os.environ.get(PARENT, os.getppid())):  # it died before the request took effect
        os._exit(1)


if __name__ == "__main__":
    _die_with_parent()
    {"discover": _discover_main, "compile": _compile_main}[sys.argv[1]]()
