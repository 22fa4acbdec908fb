"""User-facing errors: reported by the CLI as one line, without a traceback."""
import errno
import os
import re
import stat


class ProbvisError(Exception):
    """A mistake in the user's input (scene file, option, output path)."""


def is_builtin(cls):
    """Whether a class is probvis's own, not a plug-in's: a built-in's failure is a bug of probvis, a plug-in's
    is named with the plug-in."""
    return cls.__module__.split(".")[0] == "probvis"


def is_number(value, whole=False):
    """Whether `value` is a number the API takes: an int or, unless `whole`, a float, Python's or NumPy's; not a
    bool, and not a NumPy time span (`np.timedelta64` is an integer to NumPy and to `numbers`, but int() of one
    fails)."""
    import numpy as np

    if isinstance(value, (bool, np.bool_, np.timedelta64)):
        return False
    return isinstance(value, (int, np.integer) if whole else (int, float, np.integer, np.floating))


def checked_call(func, name=None):
    """`func` with a call that does not fit its signature (a misspelt keyword, a missing argument) refused as a
    ProbvisError naming the nearest argument, instead of Python's TypeError; `name` is the call's name in the
    message (a class's, for its `__init__`)."""
    import difflib
    import functools
    import inspect

    sig = inspect.signature(func)
    params = sig.parameters.values()
    names = [p.name for p in params if p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL, p.POSITIONAL_ONLY)
             and p.name != "self"]
    name = name or func.__name__
    by_position = [p.name for p in params if p.kind == p.POSITIONAL_ONLY]

    @functools.wraps(func)
    def call(*args, **kwargs):
        try:
            sig.bind(*args, **kwargs)
        except TypeError as exc:
            text, hint = str(exc), ""
            unknown = re.search(r"unexpected keyword argument '(\w+)'", text)
            if unknown:
                close = difflib.get_close_matches(unknown.group(1), names, 1)
                hint = f" (did you mean {close[0]}=?)" if close else f" (its arguments: {', '.join(names)})"
            given = [arg for arg in by_position if arg in kwargs]
            if given:
                hint = f" ({given[0]} is given first, by position: {name}(value, ...))"
            raise ProbvisError(f"{name}(): {text}{hint}") from None
        return func(*args, **kwargs)

    return call


def expect_record(value, cls, name, made_by):
    """Refuse argument `name` unless it is a `cls` record (an Experiment, a RunSummary), saying which call makes
    one: a building block of the API gets what an earlier step returned, not a path or a dict."""
    if not isinstance(value, cls):
        raise ProbvisError(f"{name} must be {made_by}, got {type(value).__name__}")


def is_path(value):
    """Whether `value` names a file: a string or any path-like object of one (`Path`, `PurePosixPath`, a class
    with `__fspath__`), not bytes."""
    return isinstance(value, str) or isinstance(value, os.PathLike) and isinstance(os.fspath(value), str)


def is_flag(value):
    """Whether `value` is True or False, Python's or NumPy's (a comparison of NumPy values gives `np.bool_`)."""
    import numpy as np

    return isinstance(value, (bool, np.bool_))


def shown(obj, conv=str):
    """`conv(obj)` (str or repr) for a message, or a placeholder where the object's own method fails: a plug-in's
    exception or value whose `__str__` or `__repr__` raises, or even exits (a message must not end the command)."""
    try:
        return conv(obj)
    except (Exception, SystemExit):  # noqa: BLE001 - whatever the plug-in's method does
        return f"<{type(obj).__name__}: its {conv.__name__}() failed>"


def missing_file(path, what):
    """Why input file `path` is not a file to read, for a one-line error: a symbolic link that loops (on Python
    before 3.13 `Path.resolve` raises a RuntimeError for those) or points to nothing, a folder, a pipe or device
    (/dev/null, a FIFO: no scene, experiment or module is one), else "`what` not found"."""
    try:
        st = os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return f"{path}: a symbolic link that loops (it or a folder on its way leads back to itself)"
        if os.path.islink(path):
            return f"{path}: a symbolic link that points to nothing"
        return f"{what} not found: {path}"
    a = "an" if what[:1] in "aeiou" else "a"
    if stat.S_ISDIR(st.st_mode):
        return f"{path} is a folder, not {a} {what}"
    if not stat.S_ISREG(st.st_mode):
        return f"{path} is not a regular file (a pipe, socket or device), not {a} {what}"
    return f"{what} not found: {path}"
