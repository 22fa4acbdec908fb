"""Run a study on Dask: one task per cell (scene x method x shadow rays x seed), cached on disk.

Workers only render; the driver loads scenes, keys every render by a content hash (scene arrays, settings,
a fingerprint of probvis's sources), writes finished renders to the cache as they arrive (atomically, so an
interrupted study loses nothing already computed) and measures errors. A cell's numbers depend only on its
key, so a study gives the same results whichever worker runs which cell.
"""
import functools
import hashlib
import inspect
import itertools
import json
import logging
import multiprocessing
import os
import resource
import signal
import socket
import struct
import sys
import threading
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import __version__
from ..errors import ProbvisError, checked_call, expect_record, is_flag, is_number, is_path, shown
from ..interrupts import deferred_interrupts
from ..io.atomic import atomic_path
from ..io.image import read_exr, write_exr
from ..io.linear_rgb import read_linear_rgb
from ..scene import open_scene
from ..scene.scene import MAX_EMISSION
from .config import MADE_BY, Experiment, MethodSpec, Timing
from .results import stats_readable


@dataclass(frozen=True)
class Task:
    """One render: a cell of the study or a scene's reference."""

    scene: str
    method: MethodSpec
    spp: int
    shadow_rays: int
    seed: int
    key: str
    reference: bool = False


@dataclass
class Render:
    """A finished render: its stats, linear RGB image and per-pixel ray-triangle tests (shadow + camera)."""

    stats: dict
    image: np.ndarray
    tests: np.ndarray


@dataclass
class RunSummary:
    """What a run produced: every cell's render (by task key) and every scene's reference."""

    tasks: list
    cells_cached: int = 0
    computed: int = 0
    renders: dict = field(default_factory=dict)  # key -> Render
    reference_images: dict = field(default_factory=dict)  # scene -> image
    reference_stats: dict = field(default_factory=dict)  # scene -> stats (None for a reference file)
    reference_noise: dict = field(default_factory=dict)  # scene -> the reference's own per-pixel relMSE


def render_task(scene, visibility, options, spp, shadow_rays, seed, threads, timing=Timing()):
    """Worker side: render one task as `timing` says (`Timing`: repeats, fewer once they took long enough),
    keeping every repeat's seconds without compilation in stats["seconds"]["repeats"], and without the scene
    load and BVH too in ["repeats_render"], each from its own render) and return what the driver stores."""
    times, render_times = [], []
    with warnings.catch_warnings(record=True) as caught:  # said by the driver, as the CLI says its own
        warnings.simplefilter("always")
        r = _repeats(scene, (visibility, options, spp, shadow_rays, seed, threads), timing, times, render_times)
    r.stats["warnings"] = list(dict.fromkeys(str(w.message).strip().splitlines()[0] for w in caught
                                             if str(w.message).strip()))
    r.stats["seconds"]["repeats"], r.stats["seconds"]["repeats_render"] = times, render_times
    return r.stats, r.image.astype(np.float32), r.aovs["triangle_tests"].astype(np.float32)


def _repeats(scene, task, timing, times, render_times):
    """The renders of `render_task`, appending their seconds to `times` and `render_times`; the last render."""
    from ..integrator import render

    visibility, options, spp, shadow_rays, seed, threads = task
    for _ in range(timing.repeats):
        try:
            r = render(scene, spp=spp, shadow_rays=shadow_rays, seed=seed, visibility=visibility,
                       visibility_options=dict(options), threads=threads)
        except (ProbvisError, MemoryError):
            raise
        except Exception as exc:  # a bug, not a lost worker: rerunning would fail the same way
            raise ProbvisError(f"visibility '{visibility}' raised {type(exc).__name__}: {shown(exc)} (a bug in the "
                               "estimator or in probvis; rerunning will not help)") from None
        sec = r.stats["seconds"]
        times.append(sec["total"] - sec["compile"])
        render_times.append(times[-1] - sec["load"] - sec["bvh"])
        if sum(times) >= timing.enough_seconds:
            break
    return r


MAX_FINGERPRINT_FILES = 2000  # Python files hashed for a plug-in's fingerprint
MIN_OPEN_FILES = 256  # below, a LocalCluster's sockets and pipes may not fit (it failed to start under 20)
FILES_PER_WORKER = 16  # the driver holds about 9 more descriptors for each worker process (measured, 1-8)


@functools.cache
def code_fingerprint():
    """SHA-256 over probvis's own Python sources: a render cached by another build of probvis is not reused."""
    h = hashlib.sha256(__version__.encode())
    root = Path(__file__).resolve().parents[1]
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def estimator_fingerprint(visibility):
    """SHA-256 of the sources of an estimator from outside probvis ('' for probvis's own): its package's Python
    files, or those beside a plug-in file (the helpers it imports); editing any of them invalidates its cached
    renders."""
    from ..visibility import BUILTIN, estimator_class

    if visibility in BUILTIN:
        return ""
    cls = estimator_class(visibility)
    path = inspect.getsourcefile(cls)
    if not path:
        return ""
    path = Path(path).resolve()
    top = sys.modules.get(cls.__module__.split(".")[0])
    if "." in cls.__module__ and getattr(top, "__file__", None):  # a package's module: the whole package
        files = sorted(Path(top.__file__).resolve().parent.rglob("*.py"))
    elif path.parent.name in ("site-packages", "dist-packages"):  # an installed single module: itself
        files = [path]
    else:  # a plug-in file: it and the modules beside it
        files = sorted(path.parent.glob("*.py"))
    h = hashlib.sha256()
    for file in files[:MAX_FINGERPRINT_FILES]:
        h.update(file.name.encode())
        h.update(file.read_bytes())
    return h.hexdigest()


def task_key(scene_hash, method, spp, shadow_rays, seed, timing=Timing(), fingerprint=None):
    """The cache key of one render; `fingerprint` is `estimator_fingerprint(method.visibility)` where the caller
    computed it once for many keys."""
    if fingerprint is None:
        fingerprint = estimator_fingerprint(method.visibility)
    blob = json.dumps([code_fingerprint(), fingerprint, scene_hash, method.visibility,
                       sorted(method.options.items()), spp, shadow_rays, seed, timing.repeats,
                       timing.enough_seconds], default=list)
    return hashlib.sha256(blob.encode()).hexdigest()[:24]


class Cache:
    """Renders on disk: `<key>.json` (the stats and a digest of the images, written last: its presence marks a
    finished render) beside `<key>.exr` (image) and `<key>-tests.exr`. An entry that does not read back as
    stored (edited, truncated, a link that loops) or whose stats lack what the tables read counts as absent: its
    render is made again."""

    def __init__(self, folder):
        self.folder = Path(folder)
        self._read = {}
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            dangling = next((p for p in (self.folder, *self.folder.parents) if p.is_symlink() and not p.exists()), None)
            why = (f"'{dangling}' is a symbolic link to '{os.readlink(dangling)}', which does not exist" if dangling
                   else exc.strerror or exc)
            raise ProbvisError(f"cannot create cache folder '{self.folder}': {why}") from None

    def _paths(self, key):
        return self.folder / f"{key}.json", self.folder / f"{key}.exr", self.folder / f"{key}-tests.exr"

    def has(self, key):
        if key not in self._read:
            self._read[key] = self._entry(key)
        return self._read[key] is not None

    def load(self, key):
        if not self.has(key):
            raise ProbvisError(f"cache entry {key} in '{self.folder}' is missing or damaged: run the same command "
                               "to render it again")
        return self._read[key]

    def _entry(self, key):
        meta, img, tests = self._paths(key)
        if not all(p.is_file() for p in self._paths(key)):
            return None
        try:
            record = json.loads(meta.read_text())
            render = Render(record["stats"], read_exr(img)[..., :3], read_exr(tests, channel="Y"))
        except (OSError, ValueError, KeyError, TypeError, ProbvisError):
            return None
        if not stats_readable(render.stats) or record.get("digest") != _digest(render):
            return None
        return render

    def store(self, key, render):
        for p in self._paths(key):  # a damaged entry's files go first (a link is removed, not written through)
            p.unlink(missing_ok=True)
        meta, img, tests = self._paths(key)
        write_exr(img, render.image)
        write_exr(tests, None, channels={"Y": render.tests})
        # as the files hold it (float32), so a render just made and one read back give the same numbers
        stored = Render(render.stats, np.asarray(render.image, np.float32), np.asarray(render.tests, np.float32))
        with atomic_path(meta) as tmp:
            Path(tmp).write_text(json.dumps({"stats": render.stats, "digest": _digest(stored)}))
        self._read[key] = stored


def _digest(render):
    """SHA-256 of a render's stats (as JSON) and images as stored (float32) with their shapes: an entry whose
    stats were edited or written by another version counts as damaged."""
    h = hashlib.sha256(json.dumps(render.stats, sort_keys=True).encode())
    for a in (render.image, render.tests):
        a = np.ascontiguousarray(a, dtype=np.float32)
        h.update(repr(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


POLL_SECONDS = 0.2  # how often the render loop looks for Ctrl-C / SIGTERM while renders run
IN_FLIGHT_PER_WORKER = 4  # renders submitted and not yet finished, per worker: the scheduler and the driver
# hold these only, so a study of any size keeps them small, and no worker waits for its next render


HANDSHAKE_SECONDS = 10  # how long a scheduler may take to greet a new connection
WORKER_WAIT_SECONDS = 10  # how long a scheduler without workers is given to get one
MAX_HANDSHAKE = 1 << 20  # bytes: a Dask handshake is a small message


def _check_reachable(scheduler):
    """A TCP scheduler that does not answer, or that is not a Dask scheduler, is named before anything is planned
    or printed (Dask's own client finds the first only after the plan's progress line; a peer that never greets
    it can hang it, and a peer that answers with text makes it read a frame of absurd length). A Dask peer writes
    its handshake as soon as it accepts a connection, a frame that starts with its length (Dask's TCP framing,
    `distributed.comm.tcp`); that is what is checked. Other transports are left to the client."""
    from urllib.parse import urlsplit

    parts = urlsplit(scheduler if "://" in scheduler else f"tcp://{scheduler}")
    if parts.scheme != "tcp":
        return
    try:
        with socket.create_connection((parts.hostname, parts.port or 8786), timeout=HANDSHAKE_SECONDS) as sock:
            head = b""
            while len(head) < 8:
                chunk = sock.recv(8 - len(head))
                if not chunk:
                    break
                head += chunk
    except TimeoutError:
        raise ProbvisError(f"the scheduler at {scheduler} accepted the connection but did not answer within "
                           f"{HANDSHAKE_SECONDS} s as a Dask scheduler does: check the address and port") from None
    except (OSError, ValueError) as exc:
        raise ProbvisError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
    size = struct.unpack("Q", head)[0] if len(head) == 8 else 0
    if not 0 < size <= MAX_HANDSHAKE:
        said = f"it answered {head!r}" if head else "it closed the connection without a word"
        raise ProbvisError(f"{scheduler} is not a Dask scheduler ({said}): check the address and port")


def _one_line(text):
    """A library's message as one line (YAML errors span several)."""
    return " ".join(str(text).split())[:500]


def _script_main():
    """Whether the process runs a user's script (not probvis's command): its workers re-import it."""
    path = getattr(sys.modules.get("__main__"), "__file__", None)
    return path is not None and "probvis" not in (Path(path).name, Path(path).parent.name)


def _open_client(workers, scheduler):
    """A Dask client: to `scheduler` when given, else to an embedded LocalCluster of `workers` processes."""
    if multiprocessing.current_process().name.startswith("Dask Worker"):
        raise ProbvisError("experiment() runs in a worker process that imported the script calling it: put the "
                           "call under `if __name__ == \"__main__\":` (Dask's workers import the script that starts "
                           "them)")
    try:
        from dask.distributed import Client, LocalCluster
    except Exception as exc:  # Dask reads its configuration as it loads (DASK_CONFIG's YAML files)
        config = f" (DASK_CONFIG={os.environ['DASK_CONFIG']})" if os.environ.get("DASK_CONFIG") else ""
        raise ProbvisError(f"cannot load Dask{config}: {type(exc).__name__}: {_one_line(exc)}") from None

    if scheduler:
        try:
            return Client(scheduler, timeout="10s"), None
        except Exception as exc:  # a transport without its settings (tls:// and its ssl_context, ucx:// and UCX)
            scheme = scheduler.split("://")[0] if "://" in scheduler else "tcp"
            hint = "" if scheme == "tcp" else (f" ({scheme}:// needs the transport's settings in Dask's configuration "
                                               "and packages; tcp://host:port needs none)")
            raise ProbvisError(f"cannot connect to the Dask scheduler at {scheduler}: {type(exc).__name__}: "
                               f"{_one_line(shown(exc))}{hint}") from None
    # The embedded cluster is ours alone: its logs are muted (a worker closed mid-heartbeat at the end of an
    # interrupted run logs a traceback at ERROR); failed renders still reach the user through their futures.
    # Ctrl-C in a terminal, or a hang-up, signals the whole process group: the workers and multiprocessing's
    # resource tracker ignore both (they inherit the ignored dispositions; a tracker killed by SIGHUP came back
    # without its records and printed tracebacks) and the driver, which defers them to a safe point, shuts the
    # workers down and says so once.
    files, most = resource.getrlimit(resource.RLIMIT_NOFILE)
    need = max(MIN_OPEN_FILES, 64 + FILES_PER_WORKER * workers)
    if files != resource.RLIM_INFINITY and files < need and (most == resource.RLIM_INFINITY or most >= need):
        try:  # the soft limit raised as far as needed, as Dask's own scheduler command does
            resource.setrlimit(resource.RLIMIT_NOFILE, (need, most))
            files = need
        except (ValueError, OSError):  # refused below
            pass
    if files != resource.RLIM_INFINITY and files < need:  # checked first: short of them, Dask's accept loop spins
        raise ProbvisError(f"cannot start a local Dask cluster of {workers} worker{'s' if workers > 1 else ''}: "
                           f"this process may open only {files} files (ulimit -n), fewer than the {need} its "
                           "sockets and pipes may need: raise it to a few thousand")
    main = threading.current_thread() is threading.main_thread()  # only there can Python set handlers
    previous = {s: signal.signal(s, signal.SIG_IGN) for s in (signal.SIGINT, signal.SIGHUP)} if main else {}
    try:
        from multiprocessing import resource_tracker

        resource_tracker.ensure_running()  # started here, if not before, with the signals ignored
        with warnings.catch_warnings():  # "port 8787 in use": another cluster's status page; ours needs none
            warnings.filterwarnings("ignore", message="Port .* is already in use")
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                                   silence_logs=logging.CRITICAL)
    except Exception as exc:  # Dask wraps the cause ("Cluster failed to start: ..."); its settings' own errors
        files, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
        hint = (f" (this process may open only {files} files, ulimit -n: raise it to a few thousand)"
                if files != resource.RLIM_INFINITY and files < MIN_OPEN_FILES else "")
        settings = sorted(k for k in os.environ if k.startswith("DASK_"))
        if not hint and settings:
            hint = f" (Dask's configuration in the environment: {', '.join(settings)})"
        if not hint and _script_main():
            hint = (" (from a script, experiment() must be called under `if __name__ == \"__main__\":`: the workers "
                    "import the script that starts them)")
        cause = exc.__cause__ or exc  # the first of the chain that says something
        while not str(cause).strip() and (cause.__cause__ or cause.__context__) is not None:
            cause = cause.__cause__ or cause.__context__
        reason = str(cause).strip() or f"{type(cause).__name__} (no message)"
        raise ProbvisError(f"cannot start a local Dask cluster: {_one_line(reason)}{hint}") from None
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    return Client(cluster), cluster


def load_scenes(exp):
    """Each of the study's scenes read (its defines applied, at the study's resolution), by name."""
    scenes = {}
    for i, spec in enumerate(exp.scenes):
        try:
            with warnings.catch_warnings(record=True) as said:
                warnings.simplefilter("always")
                scene = open_scene(spec.source, spec.defines)
        except ProbvisError as exc:
            raise ProbvisError(f"scene '{spec.name}': {exc}") from None
        unknown = sorted(set(spec.defines) - set(scene.parameters))
        if unknown:  # a misspelt define would change nothing in every cell: refused, as a built-in's is
            raise ProbvisError(f"scenes[{i}].defines: scene '{spec.name}' declares no parameter "
                               f"{', '.join(unknown)} (its parameters: {', '.join(scene.parameters) or 'none'}): "
                               "correct or remove it")
        for w in said:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        if exp.resolution is not None:
            scene = scene.with_resolution(*exp.resolution)
        scenes[spec.name] = scene
    return scenes


def plan(exp, scenes):
    """The study's tasks: (references, cells), each keyed by content hash. The cells of one scene, ray count and
    seed follow each other method after method, so that a render's turn on a busy machine, or a machine that
    slows down, weighs on every method alike rather than on one method's whole row."""
    refs, cells = [], []
    ref_method = MethodSpec("reference", exp.reference.visibility, {})
    prints = {m.visibility: estimator_fingerprint(m.visibility) for m in (ref_method, *exp.methods)}
    for spec in exp.scenes:
        h = scenes[spec.name].content_hash()
        if spec.reference is None:
            r = exp.reference
            refs.append(Task(spec.name, ref_method, r.spp, r.shadow_rays, r.seed,
                             task_key(h, ref_method, r.spp, r.shadow_rays, r.seed,
                                      fingerprint=prints[ref_method.visibility]), reference=True))
        for sr in exp.shadow_rays:
            for seed in exp.seeds:
                for m in exp.methods:
                    cells.append(Task(spec.name, m, exp.spp, sr, seed,
                                      task_key(h, m, exp.spp, sr, seed, exp.timing, prints[m.visibility])))
    return refs, cells


MEMORY_HINTS = {"film": "resolution", "photons": "options.photons", "lookups": "options.neighbours or shadow_rays",
                "batch": "spp or shadow_rays", "environment": "the environment map's size"}  # a study's keys


def _check_memory(exp, scenes):
    """Refuse, before the first render, a reference or cell whose render would not fit in memory: its render
    would refuse it only when its turn came, after the others."""
    from .. import memory
    from ..integrator import render_memory
    from ..plugin_checks import plugin_errors
    from ..visibility import estimator_class

    reference = MethodSpec("reference", exp.reference.visibility, {})
    for spec in exp.scenes:
        scene = scenes[spec.name]
        renders = [(m, exp.spp, rays) for m in exp.methods for rays in exp.shadow_rays]
        if spec.reference is None:
            renders.append((reference, exp.reference.spp, exp.reference.shadow_rays))
        for method, spp, rays in renders:
            cls = estimator_class(method.visibility)
            with plugin_errors(cls, "__init__"):
                estimator = cls(**method.options)
            try:
                memory.check(render_memory(scene, scene.defaults.replace(spp=spp, shadow_rays=rays), estimator),
                             MEMORY_HINTS, estimator.name)
            except ProbvisError as exc:
                raise ProbvisError(f"scene '{spec.name}', method '{method.name}', {rays} shadow rays: {exc}") from None


def _reference_file(spec, scene):
    """A scene's reference image from its file: readable, of the scene's size, finite."""
    try:  # EXR or PFM (the config's check), read as a texture is: grey repeated, alpha dropped
        img = read_linear_rgb(spec.reference)
    except ProbvisError as exc:
        raise ProbvisError(f"scene '{spec.name}': reference: {exc}") from None
    except Exception as exc:  # a file the image readers cannot make sense of
        raise ProbvisError(f"scene '{spec.name}': reference {spec.reference} is not a readable image "
                           f"({type(exc).__name__}: {exc})") from None
    if not np.all(np.isfinite(img)):
        raise ProbvisError(f"scene '{spec.name}': reference {spec.reference} has NaN or infinite pixels")
    want = (scene.camera.height, scene.camera.width)
    if img.shape[:2] != want:
        raise ProbvisError(f"scene '{spec.name}': reference {spec.reference} is {img.shape[1]}x{img.shape[0]}, "
                           f"the scene renders {want[1]}x{want[0]}")
    if img.min() < 0.0 or img.max() > MAX_EMISSION or not img.max() > 0.0:
        raise ProbvisError(f"scene '{spec.name}': reference {spec.reference} ranges from {img.min():g} to "
                           f"{img.max():g}: a reference is converged radiance, non-negative, not all black and at "
                           f"most {MAX_EMISSION:g} (is it the right file?)")
    return img


def _numba_threads():
    """The threads a render may use here: NUMBA_NUM_THREADS (the cores unless the environment sets fewer)."""
    import numba

    return numba.config.NUMBA_NUM_THREADS


def check_run_options(workers, scheduler, progress, log):
    """Refuse run options of the wrong kind before anything is read or rendered."""
    if not is_number(workers, whole=True) or workers < 1:
        raise ProbvisError(f"workers must be a whole number from 1, got {workers!r}")
    if scheduler is not None and not isinstance(scheduler, str):
        raise ProbvisError(f"scheduler must be an address (tcp://host:port) or None, got {type(scheduler).__name__}")
    if scheduler is not None and not scheduler.strip():  # not a local cluster instead of the one meant
        raise ProbvisError("scheduler must be an address (tcp://host:port) or None, got an empty one")
    if not is_flag(progress):
        raise ProbvisError(f"progress must be True or False, got {progress!r}")
    if log is not None and not callable(log):
        raise ProbvisError(f"log must be a function taking a line (or None), got {log!r}")


@checked_call
def run_experiment(exp, cache_dir, workers=1, scheduler=None, progress=True, log=None, scenes=None):
    """Render every reference and cell of `exp` not already in `cache_dir`; return a `RunSummary`. `scenes` are
    the study's scenes as `load_scenes` read them (read here if None)."""
    expect_record(exp, Experiment, "exp", MADE_BY)
    if not is_path(cache_dir):
        raise ProbvisError(f"cache_dir must be a folder (a path), got {type(cache_dir).__name__}")
    check_run_options(workers, scheduler, progress, log)
    cache_dir, workers = Path(cache_dir), int(workers)
    log = log or (lambda msg: print(msg, file=sys.stderr))
    if scheduler:
        _check_reachable(scheduler)
    scenes = load_scenes(exp) if scenes is None else scenes
    files = {spec.name: _reference_file(spec, scenes[spec.name]) for spec in exp.scenes
             if spec.reference is not None}  # checked before the first render
    if not scheduler:  # local workers: this machine's memory
        _check_memory(exp, scenes)
    new = [d for d in (Path(cache_dir), *Path(cache_dir).parents) if not d.exists()]  # folders this run makes
    cache = Cache(cache_dir)
    try:
        return _run(exp, scenes, files, cache, workers, scheduler, progress, log)
    except BaseException:
        for folder in new:  # nothing rendered: leave no empty folders behind
            if any(folder.iterdir()):
                break
            folder.rmdir()
        raise


def _run(exp, scenes, files, cache, workers, scheduler, progress, log):
    refs, cells = plan(exp, scenes)
    todo = [t for t in refs + cells if not cache.has(t.key)]
    out = RunSummary(tasks=cells, computed=len(todo), cells_cached=sum(cache.has(t.key) for t in cells))
    log(f"experiment '{exp.name}': {len(cells)} cells ({out.cells_cached} cached), {len(refs)} rendered "
        f"references ({sum(cache.has(t.key) for t in refs)} cached), cache {cache.folder}")
    if todo:
        _compute(todo, scenes, cache, workers, scheduler, progress, log, exp.timing)
    for spec in exp.scenes:
        if spec.reference is not None:
            out.reference_images[spec.name] = files[spec.name]
            out.reference_stats[spec.name] = None
            out.reference_noise[spec.name] = spec.reference_noise
    for t in refs:
        r = cache.load(t.key)
        out.reference_images[t.scene] = r.image.astype(np.float64)
        out.reference_stats[t.scene] = r.stats
        # None: one sample per pixel, or a pixel's samples sharing a factor (the ratio's): the noise is unknown
        out.reference_noise[t.scene] = r.stats.get("noise_relmse") or 0.0
    for t in cells:
        out.renders[t.key] = cache.load(t.key)
    for name, image in out.reference_images.items():
        if not np.any(image):  # every relMSE is then 0 and every efficiency infinite: numbers that say nothing
            warnings.warn(f"scene {name}: the reference image is black, so every method's relMSE is 0 and its "
                          "efficiency infinite in the report: check the scene's emitters and camera", stacklevel=1)
    return out


def _compute(todo, scenes, cache, workers, scheduler, progress, log, timing=Timing()):
    """Render `todo` on Dask and cache each render as it finishes. Ctrl-C and SIGTERM are deferred to the
    polling loop (`deferred_interrupts`): raised inside a Dask client call they leave a half-cancelled call
    whose clean-up logs a traceback."""
    with deferred_interrupts() as check_interrupt:
        client, cluster = _open_client(workers, scheduler)
        try:
            _run_tasks(client, workers, scheduler, todo, scenes, cache, progress, log, check_interrupt, timing)
        except (ProbvisError, KeyboardInterrupt):
            raise
        except Exception as exc:  # Dask's way of saying a worker went away: cancelled futures, lost workers
            check_interrupt()  # Ctrl-C to the process group reaches the workers too: that is an interrupt
            raise ProbvisError(f"the Dask cluster failed ({type(exc).__name__}: {exc}); finished renders are "
                               f"cached, run the same command to resume") from None
        finally:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                try:
                    client.close()
                    if cluster is not None:
                        cluster.close()
                except Exception:  # closing a cluster whose workers were interrupted may fail: nothing is lost
                    pass


def _run_tasks(client, workers, scheduler, todo, scenes, cache, progress, log, check_interrupt,
               timing=Timing()):
    """Submit the renders and store each as it finishes, checking for an interrupt every POLL_SECONDS."""
    from dask.distributed import wait
    from tqdm import tqdm

    if scheduler:  # a scheduler just started may still be waiting for its workers
        try:
            client.wait_for_workers(1, timeout=WORKER_WAIT_SECONDS)
        except TimeoutError:
            raise ProbvisError(f"the Dask scheduler at {scheduler} has no workers ({WORKER_WAIT_SECONDS} s waited): "
                               f"start some (`dask worker {scheduler}`), or run without a scheduler for a "
                               "local cluster") from None
    n_workers = len(client.scheduler_info(n_workers=-1)["workers"]) or workers
    cores = min(os.cpu_count() or 1, _numba_threads())  # NUMBA_NUM_THREADS bounds every render's threads
    threads = None if scheduler else max(1, cores // workers)
    log(f"computing {len(todo)} renders on {'scheduler ' + scheduler if scheduler else 'a LocalCluster'} "
        f"with {n_workers} worker{'s' if n_workers > 1 else ''}"
        + (f" x {threads} thread{'s' if threads > 1 else ''}" if threads else ""))
    shared = {name: client.scatter(scene, broadcast=True) for name, scene in scenes.items()}
    queue = iter(todo)  # the references first
    futures = {}

    def submit(n):
        for t in itertools.islice(queue, n):
            f = client.submit(render_task, shared[t.scene], t.method.visibility, t.method.options, t.spp,
                              t.shadow_rays, t.seed, threads, Timing() if t.reference else timing,
                              key=f"{'ref' if t.reference else 'cell'}-{t.key}",
                              priority=1 if t.reference else 0, pure=False)
            futures[f] = t

    submit(IN_FLIGHT_PER_WORKER * n_workers)
    failures = []
    with tqdm(total=len(todo), desc="renders", unit="render",
              disable=not (progress and sys.stderr.isatty())) as bar:
        while futures:
            check_interrupt()
            try:
                done, _ = wait(list(futures), timeout=POLL_SECONDS, return_when="FIRST_COMPLETED")
            except TimeoutError:
                continue
            for f in done:
                t = futures.pop(f)
                try:
                    stats, image, tests = f.result()
                except ProbvisError as exc:
                    failures.append(f"{t.scene} / {t.method.name} / {t.shadow_rays} shadow rays: {exc}")
                else:
                    for message in stats.get("warnings", ()):  # once per scene, method and text
                        warnings.warn(f"{t.scene} / {t.method.name}: {message}", stacklevel=1)
                    cache.store(t.key, Render(stats, image, tests))
                f.release()  # the scheduler (in this process, for a local cluster) forgets it, the worker its result
                bar.update(1)
            submit(len(done))
    if failures:
        kept = len(todo) - len(failures)
        raise ProbvisError(f"{len(failures)} of {len(todo)} renders failed"
                           + (f" ({kept} finished, cached): " if kept else ": ") + "; ".join(failures))
