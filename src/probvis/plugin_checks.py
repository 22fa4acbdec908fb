"""What a plug-in estimator (a `VisibilityEstimator` from outside probvis) returns, checked at every stage: its
exceptions become one error naming its class and the stage, and results of the wrong shape, kind or range are
refused before they reach the film as NaN pixels or the stats file as invalid JSON."""
import dataclasses
import json
import os
import sys
from contextlib import contextmanager

import numpy as np
import xxhash

from .accel import occluded_segments
from .cases import CASE_VERIFIED, N_CASES
from .errors import ProbvisError, is_builtin, shown
from .memory import is_byte_counts
from .shading import N_COUNTS, ShadedBatch
from .visibility import VisibilityResult

MAX_VISIBILITY = 1e12  # a segment's |estimate| beyond this is a plug-in's mistake (1/q weights stay far below)
MAX_AOV = 1e100  # a segment AOV's magnitude: sums over a pixel's segments stay finite
MAX_TESTS = 1 << 31  # node or triangle tests one segment can report (the per-pixel sums are int64)


def checked_settings(estimator):
    """The settings of an estimator instance given to `render`, checked as its class checks options: the instance
    may have been changed since it was made (`params` replaced or given values its options refuse)."""
    cls = type(estimator)
    what = f"visibility: the {cls.__qualname__} instance"
    try:
        options = estimator.settings()
        if not isinstance(options, dict):
            raise TypeError(f"settings() returned {type(options).__name__}, not a dict")
        cls.parse_options(options)
    except ProbvisError as e:
        raise ProbvisError(f"{what} has settings its class refuses: {e}") from None
    except (AttributeError, TypeError) as e:
        raise ProbvisError(f"{what} has no readable settings ({e}); make it with its class or make_estimator, whose "
                           f"__init__ (super().__init__(**options) in a subclass) sets them") from None
    return options


def checked_result(estimator, res, n):
    """`res` if it is a `VisibilityResult` of `n` segments with finite values; otherwise an error naming the
    estimator's class (a plug-in's mistake must not become NaN pixels)."""
    cls = type(estimator)
    where = f"visibility '{estimator.name}' ({cls.__module__}.{cls.__qualname__}): evaluate"
    if not isinstance(res, VisibilityResult):
        raise ProbvisError(f"{where} returned a {type(res).__name__}, not a VisibilityResult")
    masked = [f for f in ("value", "node_tests", "triangle_tests") if isinstance(getattr(res, f), np.ma.MaskedArray)]
    masked += [f"AOV '{k}'" for k, a in (res.aovs.items() if isinstance(res.aovs, dict) else ()) if
               isinstance(a, np.ma.MaskedArray)]
    if masked:  # its masked entries have no value to render
        raise ProbvisError(f"{where} returned {masked[0]} as a masked array (numpy.ma): give a plain array, the "
                           "masked entries filled (np.ma.filled)")
    for field in ("value", "node_tests", "triangle_tests"):
        arr = np.asarray(getattr(res, field))
        if arr.shape != (n,) or arr.dtype.kind not in "biuf":
            raise ProbvisError(f"{where} returned {field} of shape {arr.shape} ({arr.dtype}) for {n} segments "
                               "(real numbers, one per segment)")
    value = np.asarray(res.value, np.float64)
    if not np.all(np.isfinite(value)) or np.abs(value).max(initial=0.0) > MAX_VISIBILITY:
        bad = int((~(np.abs(value) <= MAX_VISIBILITY)).sum())
        raise ProbvisError(f"{where} returned {bad} values that are not finite or beyond ±{MAX_VISIBILITY:g}")
    for field in ("node_tests", "triangle_tests"):
        arr = np.asarray(getattr(res, field))
        if arr.dtype.kind == "f" and not np.all(np.isfinite(arr) & (arr == np.round(arr))) or np.any(arr < 0):
            raise ProbvisError(f"{where} returned {field} that are not whole numbers >= 0 (counts of tests)")
        if np.any(arr > MAX_TESTS):
            raise ProbvisError(f"{where} returned {field} above {MAX_TESTS:,} for one segment (the sums would "
                               "overflow): count the tests a segment made")
    declared = {a.name for a in estimator.aovs if a.kind == "segment"}
    if res.aovs is not None and not isinstance(res.aovs, dict):
        raise ProbvisError(f"{where} returned aovs as a {type(res.aovs).__name__}: give a dict of the declared "
                           "AOVs' names to one number per segment, or None")
    for name, arr in (res.aovs or {}).items():
        arr = np.asarray(arr)
        if name not in declared:
            raise ProbvisError(f"{where} returned AOV '{name}', which the class does not declare in `aovs`")
        if arr.shape != (n,) or arr.dtype.kind not in "biuf" or not np.all(np.isfinite(arr)):
            raise ProbvisError(f"{where} returned AOV '{name}' of shape {arr.shape} ({arr.dtype}): it needs one "
                               f"finite number per segment ({n})")
        if np.abs(arr).max(initial=0) > MAX_AOV:  # 1e308 a segment passed, and the pixels' sums were inf
            raise ProbvisError(f"{where} returned AOV '{name}' values beyond ±{MAX_AOV:g} (up to "
                               f"{float(np.abs(arr).max()):.3g}): the pixels' sums would overflow; scale them down")
    aovs = res.aovs or {}
    _refuse_missing(where, declared - set(aovs), "segment")
    if np.asarray(res.value).dtype != np.float64 or any(np.asarray(a).dtype != np.float64 for a in aovs.values()):
        # float16, float32, integers: the kernels take float64 (float16 was a NotImplementedError in them)
        return dataclasses.replace(res, value=value,
                                   aovs={k: np.asarray(a, np.float64) for k, a in aovs.items()})
    return res


def checked_shaded(estimator, shaded, batch):
    """A plug-in's `shade` result (a `ShadedBatch` for `batch`) as the film takes it, or an error naming the
    plug-in: finite radiance per camera sample, whole non-negative counts and segments per pixel, finite AOVs."""
    cls = type(estimator)
    where = f"visibility '{cls.name}' ({cls.__module__}.{cls.__qualname__}): shade()"
    n_pix, m = len(batch.pixel), len(batch.pixel) * batch.spp
    if not isinstance(shaded, ShadedBatch):
        raise ProbvisError(f"{where} returned {type(shaded).__name__}, not a ShadedBatch")
    radiance, counts, segments = (np.asarray(x) for x in shaded[:3])
    if radiance.shape != (m, 3) or radiance.dtype.kind != "f" or not np.all(np.isfinite(radiance)):
        raise ProbvisError(f"{where} returned radiance of shape {radiance.shape} ({radiance.dtype}): it needs "
                           f"finite (m, 3) floats, one row per camera sample ({m})")
    for name, arr, shape in (("counts", counts, (n_pix, N_COUNTS)), ("segments", segments, (n_pix,))):
        if arr.shape != shape or arr.dtype.kind not in "iu" or np.any(arr < 0) or np.any(arr > MAX_TESTS * m):
            raise ProbvisError(f"{where} returned {name} of shape {arr.shape} ({arr.dtype}): it needs whole "
                               f"numbers >= 0 per pixel ({n_pix})")
    if shaded.aovs is not None and not isinstance(shaded.aovs, dict):
        raise ProbvisError(f"{where} returned aovs as a {type(shaded.aovs).__name__}: give a dict of the declared "
                           "AOVs' names to one number per pixel, or None")
    aovs = shaded.aovs or {}
    _refuse_missing(where, {a.name for a in estimator.aovs if a.kind == "segment"} - set(aovs), "pixel")
    for name, arr in aovs.items():
        arr = np.asarray(arr)
        if arr.shape != (n_pix,) or arr.dtype.kind not in "biuf" or not np.all(np.isfinite(arr)):
            raise ProbvisError(f"{where} returned AOV '{name}' of shape {arr.shape}: one finite number per pixel")
    return shaded


def _refuse_missing(where, missing, per):
    """An AOV declared in `aovs` but not returned would be a silent zero image."""
    if missing:
        raise ProbvisError(f"{where} returned no AOV '{sorted(missing)[0]}', which the class declares in `aovs`: "
                           f"return one number per {per} under that name (or drop it from `aovs`)")


@contextmanager
def plugin_errors(cls, stage):
    """An exception raised by a plug-in estimator (a class from outside probvis) as one error naming its class
    and the stage; probvis's own estimators' exceptions pass through (a bug in probvis, with its traceback)."""
    try:
        yield
    except (ProbvisError, KeyboardInterrupt):
        raise
    except OSError as exc:  # the machine's, unless the plug-in's own code raised it (a data file it reads)
        if is_builtin(cls) or not _raised_in_plugin(exc):
            raise
        raise ProbvisError(f"visibility '{cls.name}' ({cls.__module__}.{cls.__qualname__}) raised "
                           f"{type(exc).__name__} in {stage}: {shown(exc)}") from None
    except MemoryError as exc:
        if is_builtin(cls) or not _raised_in_plugin(exc):  # probvis's own buffers: the
            raise  # command line's out-of-memory line, naming the settings that size them
        raise ProbvisError(f"visibility '{cls.name}' ({cls.__module__}.{cls.__qualname__}) ran out of memory in "
                           f"{stage}: an allocation of its own was larger than the machine or the process's limit "
                           "allows") from None
    except (Exception, SystemExit, GeneratorExit) as exc:  # sys.exit() too: it would end probvis without a word
        if is_builtin(cls):
            raise
        raise ProbvisError(f"visibility '{cls.name}' ({cls.__module__}.{cls.__qualname__}) raised "
                           f"{type(exc).__name__} in {stage}: {shown(exc)} (a bug in the estimator; rerunning "
                           "will not help)") from None


def _raised_in_plugin(exc):
    """Whether the innermost frame of `exc` that is neither a library's nor Python's own (NumPy allocates for
    whoever calls it) lies outside probvis: the plug-in's code, not probvis's buffers."""
    own = os.path.dirname(os.path.abspath(__file__))
    libraries = {os.path.abspath(p) for p in (sys.prefix, sys.base_prefix)}
    frames = []
    tb = exc.__traceback__
    while tb is not None:
        frames.append(os.path.abspath(tb.tb_frame.f_code.co_filename))
        tb = tb.tb_next
    for path in reversed(frames):
        if path.startswith(own + os.sep):
            return False
        if not any(path.startswith(lib + os.sep) for lib in libraries) and "site-packages" not in path:
            return True
    return False


def checked_cases(estimator, cases, like):
    """`classify`'s result if it has one int8 CASE_* value per camera sample and emitter (the shape of `like`)."""
    arr = np.asarray(cases)
    highest = (N_CASES - 1) | CASE_VERIFIED  # every value from 0 to this is a case, flagged verified or not
    cls = type(estimator)
    if arr.shape != like.shape or arr.dtype.kind not in "iu":
        raise ProbvisError(f"visibility '{estimator.name}' ({cls.__module__}.{cls.__qualname__}): classify returned "
                           f"{arr.dtype} of shape {arr.shape}; it needs CASE_* values (int8) of shape {like.shape}, "
                           "one per camera sample and emitter")
    bad = arr[(arr < 0) | (arr > highest)]
    if bad.size:
        raise ProbvisError(f"visibility '{estimator.name}' ({cls.__module__}.{cls.__qualname__}): classify returned "
                           f"{bad.size} values that are no case, such as {int(bad[0])}: use probvis.cases' "
                           "CASE_UNKNOWN, CASE_LIT, CASE_SHADOWED or CASE_PENUMBRA (0 to 3), each may be "
                           "flagged with | CASE_VERIFIED")
    return arr.astype(np.int8, copy=False)


def check_accounts(cls, stats):
    """A plug-in's own accounts within the render's: its phases' seconds within their stage's (a phase declared
    "batch" but timed in prepare made a study's render time negative), its proxy tests within the shadow
    rays' (the rest are the scene's)."""
    where = f"visibility '{cls.name}' ({cls.__module__}.{cls.__qualname__}): stats()"
    own = stats["estimator"].get("seconds") or {}
    for stage in ("prepare", "batch"):
        names = [p.name for p in cls.phases if p.stage == stage]
        spent = sum(float(own.get(n, 0.0)) for n in names)
        total = stats["seconds"]["prepare" if stage == "prepare" else "render"]
        if spent > total * 1.05 + 0.01:  # timers nest inside the stage's: a margin for their rounding only
            raise ProbvisError(f"{where}: its {stage} phases ({', '.join(names)}) took {spent:.3g} s, more than the "
                               f"{'prepare' if stage == 'prepare' else 'render (the batches)'} took ({total:.3g} s): "
                               "time each phase in the stage it declares (`Phase(name, stage)`)")
    proxy = (stats["estimator"].get("tests") or {}).get("proxy") or {}
    shadow = stats["intersection_tests"]["shadow"]
    for kind in ("node", "triangle"):
        if int(proxy.get(kind, 0)) > int(shadow[kind]):
            raise ProbvisError(f"{where}: ['tests']['proxy']['{kind}'] is {int(proxy[kind]):,}, more than the "
                               f"{int(shadow[kind]):,} {kind} tests its evaluate returned for the shadow rays: "
                               "count the proxy's tests in them too")


def checked_stats(cls, stats):
    """The estimator's `stats()` if JSON can hold it (no NaN, no arrays or sets): the stats file must be JSON."""
    if not isinstance(stats, dict):
        raise ProbvisError(f"visibility '{cls.name}' ({cls.__module__}.{cls.__qualname__}): stats() returned a "
                           f"{type(stats).__name__}, not a dict")
    memory = stats.get("memory_bytes", {})
    if not is_byte_counts(memory):
        raise ProbvisError(f"visibility '{cls.name}' ({cls.__module__}.{cls.__qualname__}): memory_bytes() must "
                           f"return a dict of byte counts (whole numbers from 0 to 2**63: no machine holds more), "
                           f"got {memory!r}")
    if memory:  # NumPy's integers (a sum of arrays' nbytes) are counts too, written as JSON's
        stats = {**stats, "memory_bytes": {k: int(v) for k, v in memory.items()}}
    try:
        json.dumps(stats, allow_nan=False)
    except (TypeError, ValueError, RecursionError) as exc:
        raise ProbvisError(f"visibility '{cls.name}' ({cls.__module__}.{cls.__qualname__}): stats() returned a value "
                           f"JSON cannot hold ({type(exc).__name__}: {str(exc)[:200]}); return numbers, strings, "
                           "lists and dicts") from None
    if not is_builtin(cls):
        _check_read_keys(cls, stats)
    return stats


def _whole(x):
    return isinstance(x, int) and not isinstance(x, bool) and x >= 0


def _check_read_keys(cls, stats):
    """The keys of a plug-in's stats that studies read (`experiments.results`): of the types they read, or an
    error now rather than a traceback after every render."""
    where = f"visibility '{cls.name}' ({cls.__module__}.{cls.__qualname__}): stats()"
    tests, seconds = stats.get("tests", {}), stats.get("seconds", {})
    if not (isinstance(tests, dict) and all(isinstance(v, dict) and all(_whole(c) for c in v.values())
                                            for v in tests.values())):
        raise ProbvisError(f"{where}['tests'] must map a geometry to its counts (whole numbers >= 0), got "
                           f"{tests!r:.200}")
    if not (isinstance(seconds, dict) and all(isinstance(v, (int, float)) and not isinstance(v, bool) and v >= 0
                                              for v in seconds.values())):
        raise ProbvisError(f"{where}['seconds'] must map a phase to its seconds (numbers >= 0), got {seconds!r:.200}")
    if not isinstance(stats.get("biased", False), bool):
        raise ProbvisError(f"{where}['biased'] must be True or False, got {stats['biased']!r:.100}")


def arrays_digest(integrator):
    """XXH3 of the arrays a plug-in estimator reaches through the integrator (the kernels' scene, its textures,
    the emitters, the BVH): they are the caller's and the render's own, so a plug-in must not change them."""
    h = xxhash.xxh3_128()
    for record in (integrator.scene_arrays, integrator.surface.textures, (integrator.surface.back_material,),
                   integrator.emitters.arrays, integrator.bvh.arrays):
        for a in record:
            if isinstance(a, np.ndarray):
                h.update(np.ascontiguousarray(a).reshape(-1).view(np.uint8))
    return h.digest()


def check_unchanged(estimator, integrator, digest):
    """An error if a plug-in changed those arrays during its render (`digest`: theirs before `prepare`)."""
    if arrays_digest(integrator) != digest:
        cls = type(estimator)
        raise ProbvisError(f"visibility '{cls.name}' ({cls.__module__}.{cls.__qualname__}) changed the arrays of the "
                           "scene, its emitters or its BVH that the integrator handed it: the image is not the "
                           "scene's (a bug in the estimator: treat them as read-only)")


def checked_fused(integrator, estimator, n_checked=4096):
    """A plug-in's FUSED_EXACT path: the fused kernel renders exact visibility in place of its `evaluate`, so its
    `evaluate` on the first batch's first `n_checked` segments must return exactly that, or the image would not
    be the estimator's. Returns the path's `shade`."""
    checked = False

    def shade(batch):
        nonlocal checked
        if not checked:
            checked = True
            q = integrator.shadow_query(batch)
            q = dataclasses.replace(q, **{f.name: getattr(q, f.name)[:n_checked] for f in dataclasses.fields(q)
                                          if getattr(q, f.name) is not None})
            value = checked_result(estimator, estimator.evaluate(q), len(q.tmax)).value
            exact = 1.0 - occluded_segments(integrator.bvh, q.origin, q.direction, q.tmax, q.point)[0]
            if not np.array_equal(value, exact):
                k = int(np.flatnonzero(value != exact)[0])
                cls = type(estimator)
                raise ProbvisError(f"visibility '{estimator.name}' ({cls.__module__}.{cls.__qualname__}): "
                                   "render_path() returned FUSED_EXACT, which renders exact visibility instead of "
                                   f"evaluate, but evaluate returned {value[k]:g} where it is {exact[k]:g}: return "
                                   "STAGED (or make evaluate exact)")
        return integrator.shade_exact(batch)

    return shade
