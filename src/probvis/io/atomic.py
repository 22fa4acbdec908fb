"""Outputs written to a temporary name beside them and renamed when whole (`atomic_path`), and a command's outputs
renamed together, all or none (`staged_writes`)."""
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

from ..errors import ProbvisError

try:
    import fcntl
except ImportError:  # not POSIX: no lock, and no cleaning up after another process
    fcntl = None

_staged = None  # (temporary, destination, name given) of the writes `staged_writes` holds back (None: inactive)


@contextmanager
def staged_writes():
    """Hold back the renames of every `atomic_path` write inside the block until all of them succeeded: a
    command's outputs appear together or not at all (one failing write leaves none of the others)."""
    global _staged
    outer, _staged = _staged, []
    try:
        yield
        _commit(_staged)
    finally:
        for tmp, _, _ in _staged:
            if os.path.exists(tmp):
                os.unlink(tmp)
        _staged = outer


def _commit(staged):
    """Rename each (temporary, destination, name given) of `staged` over its destination, all or none: a
    destination a rename cannot replace (a folder) is found before the first; a rename that fails later puts
    back what the earlier ones replaced (kept as hard links meanwhile) and removes what they created."""
    for _, path, shown in staged:
        if os.path.isdir(path):
            raise ProbvisError(f"cannot write '{shown}': it is a folder")
    done = []
    try:
        for tmp, path, shown in staged:
            previous = f"{tmp}.previous" if os.path.lexists(path) else None
            if previous is not None:
                try:
                    os.link(path, previous)
                except OSError:  # a file system without hard links: this one cannot be put back
                    previous = None
            try:
                os.replace(tmp, path)
            except OSError as exc:
                if previous is not None:
                    os.unlink(previous)
                raise ProbvisError(f"cannot write '{shown}': {exc.strerror or exc}") from None
            done.append((path, previous))
    except BaseException:
        for path, previous in reversed(done):
            try:
                os.replace(previous, path) if previous is not None else os.unlink(path)
            except OSError:
                pass
        raise
    for _, previous in done:
        if previous is not None and os.path.lexists(previous):
            os.unlink(previous)


TEMP_PREFIX = ".pv-"


@contextmanager
def exclusive_folder(folder, what, own=()):
    """Hold `folder` (made if missing) for this process alone during the block: a lock on the folder itself,
    which the system drops when the process ends however it ends; another process that holds it gets a one-line
    error naming `what`. Once held, the hidden temporaries (`temp_beside`'s) that a process killed while writing
    left in it and in its subfolders `own` are removed, and folders made here are removed again if the block
    fails and leaves them empty. Where the file system cannot lock (NFS without locking), the block runs
    without the lock and removes no temporaries (another process's may be live)."""
    folder = Path(folder)
    made = [d for d in (folder, *folder.parents) if not d.exists()]
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd = os.open(folder, os.O_RDONLY)
    except OSError as exc:
        raise ProbvisError(f"cannot open {what} '{folder}': {exc.strerror or exc}") from None
    try:
        held = _lock(fd, f"{what} '{folder}'")
        try:
            if held:
                for sub in ("", *own):
                    _remove_temporaries(folder / sub)
            yield folder
        except BaseException:
            for d in made:  # a process refused the lock raised above, before touching what the holder made
                try:
                    if d.is_dir() and not any(d.iterdir()):
                        d.rmdir()
                except OSError:
                    break
            raise
    finally:
        if fcntl is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_UN)  # a forked child's copy of the descriptor would keep it otherwise
            except OSError:
                pass
        os.close(fd)


def _lock(fd, named):
    """Lock the open folder `fd` for this process; False where the file system cannot lock. Refuses a folder
    another process holds."""
    if fcntl is None:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise ProbvisError(f"{named} is being written by another probvis process: wait for it to end, or give "
                           "another folder") from None
    except OSError:  # NFS (EBADF on a folder opened to read, ENOLCK without its lock service)
        return False
    return True


def _remove_temporaries(folder):
    """Remove `temp_beside`'s files directly in `folder` (not below it: another process's folder may be)."""
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return
    for entry in entries:
        if entry.name.startswith(TEMP_PREFIX) and entry.is_file(follow_symlinks=False):
            try:
                os.unlink(entry.path)
            except OSError:
                pass


def temp_beside(folder, suffix):
    """A new hidden temporary file in `folder`, (fd, path): a short name (.pv- and 8 characters), so that any
    output name the file system takes can be written through it."""
    return tempfile.mkstemp(prefix=TEMP_PREFIX, suffix=suffix, dir=folder)


@contextmanager
def atomic_path(path):
    """Yield a temporary path beside `path` (beside its target, for a symbolic link: the link is written
    through, as a plain write would); rename it over `path` only when the block succeeds (inside
    `staged_writes`, when all of them did)."""
    if not isinstance(path, (str, os.PathLike)) or not str(path):
        raise ProbvisError(f"an output path must be a file name (str or Path), got {path!r}")
    shown, path = path, Path(os.path.realpath(path))
    try:
        fd, tmp = temp_beside(path.parent or ".", path.suffix)
    except OSError as exc:
        missing = not os.path.isdir(path.parent)  # /proc exists and says ENOENT: its own reason
        raise ProbvisError(f"cannot write '{shown}': " + (f"folder '{Path(shown).parent}' does not exist" if missing
                                                          else exc.strerror or str(exc))) from None
    os.close(fd)
    try:
        yield tmp
        if os.path.getsize(tmp) == 0:  # OpenEXR's writer reports no error when it can write nothing
            raise ProbvisError(f"cannot write '{shown}': nothing could be written (a full disk, or a file size limit: "
                               "ulimit -f)")
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; give the file the usual permissions
        if _staged is not None:
            _staged.append((tmp, path, shown))
            return
        os.replace(tmp, path)
    except OSError as exc:
        raise ProbvisError(f"cannot write '{shown}': {exc.strerror or exc}") from None
    except RuntimeError as exc:  # OpenEXR's writer: "Failed to write ... image file "<tmp>". File too large."
        raise ProbvisError(f"cannot write '{shown}': {str(exc).rsplit(chr(34) + '. ', 1)[-1].rstrip('.')}") from None
    finally:
        if os.path.exists(tmp) and (_staged is None or all(tmp != t for t, _, _ in _staged)):
            os.unlink(tmp)
