"""What a compiled library prints, captured: OpenEXR reports a failed read as a line on the standard output (through
pybind11's print, i.e. Python's sys.stdout) and its C core another on the standard error, then returns; probvis
turns them into its one error line instead of letting them through."""
import ctypes
import io
import os
import sys
import tempfile
from contextlib import contextmanager, redirect_stdout


@contextmanager
def library_output():
    """Capture what a library prints while the block runs (through Python's sys.stdout, as pybind11's print does,
    or on the process's standard output and error, as OpenEXR's C core does); yields a function that returns it so
    far, as one line."""
    libc = ctypes.CDLL(None)
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    with tempfile.TemporaryFile() as sink, redirect_stdout(io.StringIO()) as text:
        os.dup2(sink.fileno(), 1)
        os.dup2(sink.fileno(), 2)

        def said():
            libc.fflush(None)
            sink.seek(0)
            return " ".join((text.getvalue() + sink.read().decode(errors="replace")).split())

        try:
            yield said
        finally:
            libc.fflush(None)
            for fd, copy in enumerate(saved, 1):
                os.dup2(copy, fd)
                os.close(copy)
