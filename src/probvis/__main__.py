"""The `probvis` console command and `python -m probvis`: starts the command line, and reports a start that
fails (Ctrl-C or SIGTERM while the libraries load, a compiled library that cannot load under the process's
limits) in one line."""
import errno
import importlib.util
import os
import re
import resource
import signal
import sys
import warnings

from .interrupts import stop_signals

_stopped = []  # stop signals received while the libraries load


def _terminate(signum, frame):
    """Ctrl-C, SIGTERM or SIGHUP while the libraries load stops the start, and is remembered: a library's bare
    `except:` around an optional import of its own may swallow the KeyboardInterrupt (the start then ran on)."""
    _stopped.append(signum)
    raise KeyboardInterrupt


def _done(status):
    """The command is over (its outputs written and closed, or its failure said): leave with its status at once.
    The interpreter's own teardown (Dask's, Numba's and LLVM's modules) runs after Python has put the default
    signal handlers back, so a stop signal in it killed a finished study (exit 143, no message)."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):  # a failing stdout was the command's to report
            pass
    os._exit(status)


def _address_limit():
    """The process's address-space limit in MiB (ulimit -v), or None."""
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
    soft, _ = resource.getrlimit(resource.RLIMIT_STACK)
    if soft == resource.RLIM_INFINITY or soft >= MIN_STACK_KIB << 10:
        return None
    return (f"probvis: error: the stack limit of {soft >> 10} KiB (ulimit -s) is too small: probvis needs at least "
            f"{MIN_STACK_KIB} KiB (the usual default is 8192)")


def _start_failure(exc):
    """The one line for a library that failed to load: the process's address-space limit is the usual cause, or
    its open-file limit (ulimit -n; resource is imported up front: loading it takes a file too)."""
    if isinstance(exc, OSError) and exc.errno == errno.EMFILE:
        soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
        return (f"probvis: error: cannot start under the open-file limit of {soft} (ulimit -n): too many open files; "
                "raise the limit")
    limit = _address_limit()
    if limit is not None:
        return (f"probvis: error: cannot load its libraries under the address-space limit of {limit} MiB "
                f"(ulimit -v): raise the limit ({type(exc).__name__})")
    reason = str(exc).split(". ")[0].splitlines()[0] if str(exc) else ""
    return f"probvis: error: cannot load its libraries ({type(exc).__name__}: {reason}): reinstall probvis"


MAX_NUMBA_THREADS = 1024  # beyond, thread creation fails or the process crashes (65536 on a 2-core machine)
_THREADING_LAYERS = ("default", "safe", "forksafe", "threadsafe", "omp", "workqueue", "tbb")


def _bad_setting(name, value, want):
    hint = " (--threads bounds a render's threads)" if name.endswith("NUM_THREADS") else ""
    return f"probvis: error: {name}='{value}' is not {want}: unset it or correct it{hint}"


def _bad_environment():
    """The one line for an environment setting Numba or OpenMP would fail on with a traceback, a crash or a line
    of their own (NUMBA_NUM_THREADS=0, NUMBA_THREADING_LAYER=tbb without TBB, OMP_NUM_THREADS=abc)."""
    env = os.environ
    threads = env.get("NUMBA_NUM_THREADS")
    if threads is not None and not (threads.strip().isdigit() and threads.isascii()
                                    and 0 < int(threads) <= MAX_NUMBA_THREADS):
        return _bad_setting("NUMBA_NUM_THREADS", threads, f"a thread count from 1 to {MAX_NUMBA_THREADS}")
    for name in ("NUMBA_CACHE_DIR", "PROBVIS_CACHE_DIR"):
        if env.get(name) and not env[name].strip():
            return _bad_setting(name, env[name], "a folder (it is blank: it would make a folder named by spaces)")
    layer = env.get("NUMBA_THREADING_LAYER")
    if layer is not None and layer.strip().lower() not in _THREADING_LAYERS:
        return _bad_setting("NUMBA_THREADING_LAYER", layer, f"one of Numba's threading layers "
                                                           f"({', '.join(_THREADING_LAYERS)})")
    if layer is not None and layer.strip().lower() == "tbb" and importlib.util.find_spec("tbb") is None:
        return _bad_setting("NUMBA_THREADING_LAYER", layer, "usable here: Intel TBB is not installed (pip install tbb)")
    priority = env.get("NUMBA_THREADING_LAYER_PRIORITY")
    if priority is not None and sorted(priority.split()) != ["omp", "tbb", "workqueue"]:
        return _bad_setting("NUMBA_THREADING_LAYER_PRIORITY", priority, "an order of tbb, omp and workqueue "
                            "(all three, separated by spaces)")
    cache = env.get("PROBVIS_CACHE_DIR")
    if cache and cache.strip() and os.path.expanduser(cache).startswith("~"):
        return _bad_setting("PROBVIS_CACHE_DIR", cache, "a folder: it names the home of a user this machine does not "
                            "know")
    opt = env.get("NUMBA_OPT")
    if opt is not None and opt.strip().lower() not in ("0", "1", "2", "3", "max"):
        return _bad_setting("NUMBA_OPT", opt, "an optimisation level (0, 1, 2, 3 or max)")
    return _openmp_complaint() or _stack_too_small() or _address_space_too_small()


def _openmp_complaint():
    """The one line for an OMP_* or GOMP_* variable that OpenMP's runtime (libgomp, which Numba's threading layer
    loads) cannot use. libgomp reads them once, as it loads, and reports a bad one on a line of its own, then
    ignores it: loaded here with the standard error captured, its complaint becomes probvis's line."""
    import ctypes
    import threading

    # through a pipe, not a temporary file (under a file size limit of 0 none can be made), drained as it fills
    # (the loader may say more than a pipe holds: LD_DEBUG, OMP_DISPLAY_ENV)
    read, write = os.pipe()
    chunks = []
    drain = threading.Thread(target=lambda: chunks.extend(iter(lambda: os.read(read, 65536), b"")), daemon=True)
    drain.start()
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        os.dup2(write, 2)
        os.close(write)
        write = None
        ctypes.CDLL("libgomp.so.1")
    except OSError:  # another OpenMP runtime, or none: Numba uses its own threading layer then
        pass
    finally:
        if write is not None:
            os.close(write)
        os.dup2(saved, 2)  # the pipe's last writer closed: the drain ends at what libgomp said
        os.close(saved)
        drain.join()
        os.close(read)
    text = b"".join(chunks).decode(errors="replace")
    bad = re.search(r"Invalid value for envi\w* variable (\w+)", text)
    if bad:
        return _bad_setting(bad.group(1), os.environ.get(bad.group(1), ""), "a value OpenMP (libgomp) accepts")
    return None


class _NoBlasProbe:
    """An import hook of the command's own process. Numba's NumPy support, as it loads at the first kernel call,
    imports scipy.linalg only to learn whether np.convolve and np.correlate may call BLAS (`numba.np.arraymath`):
    0.13 s of every start, for functions no probvis kernel uses. That one import is refused (the probe then
    answers no BLAS); scipy.linalg imported for any other reason, or by a kernel that does linear algebra
    (`numba.np.linalg` imports it as it compiles one), loads as usual."""

    def find_spec(self, name, path=None, target=None):
        if name == "scipy.linalg":
            probing = sys.modules.get("numba.np.arraymath")
            if probing is not None and getattr(probing.__spec__, "_initializing", False):
                raise ImportError("scipy.linalg is not loaded for Numba's start-up BLAS probe")
        return None


def main():
    sys.meta_path.insert(0, _NoBlasProbe())
    if sys.stderr is None:  # closed (`2>&-`): the command goes on, its messages go nowhere (a closed standard
        sys.stderr = open(os.devnull, "w")  # output is the command's to report, on stderr)
    previous = {}
    try:  # a signal caught while the later handlers are set is an interrupt too
        for s in stop_signals():
            previous[s] = signal.signal(s, _terminate)
        problem = _bad_environment()  # checked under the handlers: a signal this early is an interrupt too
        if problem:
            print(problem, file=sys.stderr)
            return 1
        with warnings.catch_warnings(record=True) as said:  # the filters as they are: what they show is recorded
            from .cli import main as cli_main
        for w in said:  # Numba parses its NUMBA_* variables as it loads, and only warns of one it cannot read
            found = re.search(r"Environment variable '(\w+)' is defined but its associated value '(.*)' could not "
                              r"be parsed", str(w.message))
            if found:
                print(_bad_setting(found.group(1), found.group(2), "a value Numba can read"), file=sys.stderr)
                return 1
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)
        if _stopped:  # the interrupt was swallowed inside an import
            raise KeyboardInterrupt
    except KeyboardInterrupt:
        print("probvis: interrupted, nothing written", file=sys.stderr, flush=True)
        # at once: a normal exit after an interrupted import sometimes died by SIGINT (-2) instead, most likely
        # through CPython's unhandled-KeyboardInterrupt flag left set by the import
        os._exit(130)
    except (ImportError, OSError, MemoryError) as exc:
        print(_start_failure(exc), file=sys.stderr)
        return 1
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    try:
        return _done(cli_main())
    except (ImportError, OSError, SystemError) as exc:  # a library loaded later, or the interpreter's own allocation
        if _address_limit() is None or (isinstance(exc, OSError) and exc.errno not in (None, errno.ENOMEM)):
            raise
        print(_start_failure(exc), file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
