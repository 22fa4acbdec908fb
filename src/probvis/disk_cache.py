"""The on-disk cache of derived geometry (proxies, shells): arrays keyed by a 128-bit hash (XXH3) of what they
were derived from, under `$PROBVIS_CACHE_DIR` (default `~/.cache/probvis`). Entries are written atomically; a
damaged entry is rebuilt and a cache that cannot be written is a warning, never an error."""
import math
import os
import pwd
import warnings
import zipfile
import zlib
from pathlib import Path

import numpy as np
import xxhash

from . import memory


def cache_dir(kind):
    """Where entries of `kind` ("proxies", "shells", "closed", "parts", "structure", "plans") are cached."""
    folder = os.environ.get("PROBVIS_CACHE_DIR")  # '~' expanded where a quoted value kept it from the shell
    if folder:
        return Path(os.path.expanduser(folder)) / kind
    home = os.environ.get("HOME") or pwd.getpwuid(os.getuid()).pw_dir  # an empty HOME is not the root folder
    return Path(home) / ".cache" / "probvis" / kind


def content_key(label, *arrays):
    """XXH3-128 of a label (what is derived, and how) and the arrays it is derived from: a few milliseconds for
    a million triangles, where SHA-256 of their bytes took a tenth of a second on every run."""
    h = xxhash.xxh3_128(label.encode())
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.reshape(-1).view(np.uint8))
    return h.hexdigest()


def fits(arrays, expect):
    """Whether loaded `arrays` hold what `expect` describes: per name (shape, dtype kinds), None in a shape for
    any length; floats finite."""
    for name, (shape, kinds) in expect.items():
        a = arrays.get(name)
        if (a is None or a.dtype.kind not in kinds or a.ndim != len(shape)
                or any(want is not None and got != want for got, want in zip(a.shape, shape))
                or (a.dtype.kind == "f" and not np.all(np.isfinite(a)))):
            return False
    return True


def _check_sizes(path):
    """ValueError if an array of the .npz at `path` declares more bytes than its member holds, or all of them
    more than the process could allocate (NumPy would allocate the declared size before reading: a damaged
    header asked for terabytes, and an archive of zeros can honestly inflate to more than the machine holds)."""
    fmt = np.lib.format
    total = 0
    with zipfile.ZipFile(path) as archive:
        for info in archive.infolist():
            with archive.open(info) as member:
                version = fmt.read_magic(member)
                read = fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0
                shape, _, dtype = read(member)
                if math.prod(shape) * dtype.itemsize > info.file_size:
                    raise ValueError(f"{info.filename} declares {shape} beyond its {info.file_size} bytes")
                total += info.file_size
    if total > memory.available():
        raise ValueError(f"{path} would inflate to {total} bytes, more than this process can allocate")


def load(kind, key, expect=None):
    """The dict of arrays stored under `key`, or None where there is none or it cannot be read or does not hold
    what `expect` describes (`fits`: a damaged or foreign file)."""
    path = cache_dir(kind) / f"{key}.npz"
    try:
        if not path.is_file():
            return None
        _check_sizes(path)
        with np.load(path, allow_pickle=False) as f:
            arrays = {k: f[k] for k in f.files}
    except (OSError, ValueError, KeyError, EOFError, MemoryError, zipfile.BadZipFile, zlib.error):
        return None
    digest = arrays.pop(DIGEST, None)
    if digest is None or digest.tobytes() != _digest(arrays):  # changed since it was stored, or not ours
        return None
    return arrays if expect is None or fits(arrays, expect) else None


DIGEST = "__digest__"  # an entry's own member: XXH3 of the others as stored


def _digest(arrays):
    h = xxhash.xxh3_128()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name} {a.dtype.str}{a.shape}".encode())
        h.update(a.reshape(-1).view(np.uint8))
    return h.digest()


_UNWRITABLE = set()  # cache folders a store failed in, this process


def store(kind, key, arrays):
    """Store a dict of arrays under `key`, atomically; a cache that cannot be written is a warning."""
    path = cache_dir(kind) / f"{key}.npz"
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as f:
            np.savez(f, **arrays, **{DIGEST: np.frombuffer(_digest(arrays), np.uint8)})
        os.replace(tmp, path)
    except OSError as exc:
        try:
            tmp.unlink(missing_ok=True)
        except OSError:
            pass
        if path.parent not in _UNWRITABLE:  # once per folder, whichever estimator stores there next
            _UNWRITABLE.add(path.parent)
            warnings.warn(f"{kind}: cannot cache in {path.parent} ({exc.strerror or exc})", stacklevel=3)



def load_or_build(kind, key, build, use_cache=True, expect=None):
    """(arrays, cached): the dict of arrays stored under `key` (`load`), or `build()`'s (a dict of arrays, or
    None when there is nothing to store), stored for next time. A damaged or foreign entry is rebuilt."""
    arrays = load(kind, key, expect) if use_cache else None
    if arrays is not None:
        return arrays, True
    out = build()
    if out is not None and use_cache:
        store(kind, key, out)
    return out, False
