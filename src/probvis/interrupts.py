"""Deferred interrupts: hold Ctrl-C (and other stop signals) while code that must not be interrupted midway
runs, and raise KeyboardInterrupt at the next safe point instead.

Python raises KeyboardInterrupt wherever the main thread happens to be. Inside a Numba kernel that leaves the
interpreter in an error state; inside Dask's client calls it leaves a half-cancelled operation whose clean-up
callback fails with a logged traceback. Both callers poll `check()` at points where stopping is clean.
"""
import signal
import threading
from contextlib import contextmanager


@contextmanager
def deferred_interrupts(signals=(signal.SIGINT, signal.SIGTERM)):
    """Record `signals` instead of acting on them inside the block; the yielded `check()` raises
    KeyboardInterrupt if one arrived, and so does leaving the block. Off the main thread (where Python cannot
    set handlers) nothing is deferred."""
    if threading.current_thread() is not threading.main_thread():
        yield lambda: None
        return
    pending = []
    previous = {s: signal.signal(s, lambda signum, frame: pending.append(signum)) for s in signals}

    def check():
        if pending:
            raise KeyboardInterrupt

    try:
        yield check
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    check()
