"""Deferred interrupts: hold Ctrl-C (and other stop signals) while code that must not be interrupted midway
runs, and raise KeyboardInterrupt at the next safe point instead.

Python raises KeyboardInterrupt wherever the main thread happens to be. Inside a Numba kernel that leaves the
interpreter in an error state; inside Dask's client calls it leaves a half-cancelled operation whose clean-up
callback fails with a logged traceback. Both callers poll `check()` at points where stopping is clean. Inside
Numba's compiler (a first run's minutes of Python code, no kernel running) a signal acts at once, and so does
a second one anywhere (the user insists: a plug-in may be stuck inside a batch that never ends).
"""
import signal
import sys
import threading
from contextlib import contextmanager


def stop_signals():
    """The signals that stop a command as Ctrl-C does: SIGINT, SIGTERM (a batch system's stop) and SIGHUP (the
    terminal or ssh session closed), unless SIGINT or SIGHUP is ignored (a shell script's `probvis ... &`,
    `nohup`), as Python itself leaves an ignored SIGINT ignored."""
    return tuple(s for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
                 if s == signal.SIGTERM or signal.getsignal(s) is not signal.SIG_IGN)


@contextmanager
def deferred_interrupts(signals=None):
    """Record `signals` (default `stop_signals()`) instead of acting on them inside the block; the yielded
    `check()` raises KeyboardInterrupt if one arrived, and so does leaving the block. Off the main thread (where
    Python cannot set handlers) nothing is deferred."""
    if threading.current_thread() is not threading.main_thread():
        yield lambda: None
        return
    signals = stop_signals() if signals is None else signals
    pending = list(_requested)  # a stop that arrived before, and that the code it interrupted swallowed
    _received.clear()

    def record(signum, frame):
        insisted = bool(pending)
        pending.append(signum)
        _received.append(signum)
        _since_reset.append(signum)  # for `check_stop`: the block's KeyboardInterrupt may be swallowed
        if _compiling() or insisted:  # Numba's compiler is Python code, no kernel runs: stop now, not after
            raise KeyboardInterrupt  # minutes; a second signal: the batch does not end (a plug-in stuck in it)

    previous = {s: signal.signal(s, record) for s in signals}

    def check():
        if pending:
            raise KeyboardInterrupt

    try:
        yield check
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    check()


_received = []  # the stop signals the latest deferral recorded
_since_reset = []  # every stop signal since the command started (`reset_stop`), deferred or not
_requested = []  # stop signals `stop_now` raised on: remembered, since a plug-in's `except BaseException` may eat one


def stop_now(signum, frame):
    """A stop signal's handler outside a deferral: KeyboardInterrupt at once, and remembered, so that every later
    safe point (`deferred_interrupts`, `check_stop`) stops too if the code it interrupted swallowed it."""
    _requested.append(signum)
    _since_reset.append(signum)
    raise KeyboardInterrupt


def check_stop():
    """KeyboardInterrupt if a stop signal arrived since `reset_stop` (at a command's safe points: before writing
    outputs, at its end), whether or not the code it interrupted swallowed the KeyboardInterrupt."""
    if _since_reset:
        raise KeyboardInterrupt


def reset_stop():
    """Forget earlier stop signals: a new command starts (the API may run several in one process)."""
    _requested.clear()
    _received.clear()
    _since_reset.clear()


def interrupt_received():
    """Whether a stop signal arrived inside a deferral: an error that follows it is the interrupt's doing."""
    return bool(_received)


def _compiling():
    """Whether this thread is inside Numba's compiler (a first run compiles for minutes)."""
    lock = getattr(sys.modules.get("numba.core.compiler_lock"), "global_compiler_lock", None)
    return lock is not None and lock.is_locked()
