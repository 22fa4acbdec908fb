"""The `probvis` console command and `python -m probvis`: starts the command line, and reports a start that
fails (Ctrl-C or SIGTERM while the libraries load, a compiled library that cannot load under the process's
limits) in one line."""
import os
import signal
import sys


def _terminate(signum, frame):
    """SIGTERM while the libraries load stops the start as Ctrl-C does."""
    raise KeyboardInterrupt


def _address_limit():
    """The process's address-space limit in MiB (ulimit -v), or None."""
    import resource

    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    return None if soft == resource.RLIM_INFINITY else soft >> 20


MIN_STACK_KIB = 1024  # numpy's import crashes below about 90 KiB, the interpreter below 76; scenes need more
MIN_ADDRESS_MIB = 640  # the libraries and a tiny render need about 500 MiB of address space; between 350 and 550
# OpenBLAS's start-up retries a failing allocation for ever (a hang), or gives up with a message of its own


def _address_space_too_small():
    """The one line for an address-space limit (ulimit -v) too small to load the libraries and render."""
    limit = _address_limit()
    if limit is None or limit >= MIN_ADDRESS_MIB:
        return None
    return (f"probvis: error: the address-space limit of {limit} MiB (ulimit -v) is too small: probvis needs at "
            f"least {MIN_ADDRESS_MIB} MiB to load its libraries, and more for a scene: raise the limit")


def _stack_too_small():
    """The one line for a stack limit (ulimit -s) too small to start: below it the process would crash."""
    import resource

    soft, _ = resource.getrlimit(resource.RLIMIT_STACK)
    if soft == resource.RLIM_INFINITY or soft >= MIN_STACK_KIB << 10:
        return None
    return (f"probvis: error: the stack limit of {soft >> 10} KiB (ulimit -s) is too small: probvis needs at least "
            f"{MIN_STACK_KIB} KiB (the usual default is 8192)")


def _start_failure(exc):
    """The one line for a library that failed to load: the process's address-space limit is the usual cause."""
    limit = _address_limit()
    if limit is not None:
        return (f"probvis: error: cannot load its libraries under the address-space limit of {limit} MiB "
                f"(ulimit -v): raise the limit ({type(exc).__name__})")
    reason = str(exc).split(". ")[0].splitlines()[0] if str(exc) else ""
    return f"probvis: error: cannot load its libraries ({type(exc).__name__}: {reason}): reinstall probvis"


def _bad_environment():
    """The one line for an environment setting Numba would fail on with a traceback (NUMBA_NUM_THREADS=0)."""
    threads = os.environ.get("NUMBA_NUM_THREADS")
    if threads is not None and not (threads.strip().isdigit() and threads.isascii() and int(threads) > 0):
        return (f"probvis: error: NUMBA_NUM_THREADS='{threads}' is not a thread count: unset it, or give a positive "
                "whole number (--threads bounds a render's threads)")
    return _stack_too_small() or _address_space_too_small()


def main():
    problem = _bad_environment()
    if problem:
        print(problem, file=sys.stderr)
        return 1
    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        from .cli import main as cli_main
    except KeyboardInterrupt:
        print("probvis: interrupted, nothing written", file=sys.stderr, flush=True)
        # at once: a normal exit after an interrupted import sometimes died by SIGINT (-2) instead, most likely
        # through CPython's unhandled-KeyboardInterrupt flag left set by the import
        os._exit(130)
    except (ImportError, OSError, MemoryError) as exc:
        print(_start_failure(exc), file=sys.stderr)
        return 1
    finally:
        signal.signal(signal.SIGTERM, previous)
    try:
        return cli_main()
    except (ImportError, OSError, SystemError) as exc:  # a library loaded later, or the interpreter's own allocation
        if _address_limit() is None:
            raise
        print(_start_failure(exc), file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
