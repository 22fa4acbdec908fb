"""Memory a render needs, estimated from its settings before anything large is allocated.

`estimate` adds up what is resident already, the film (per-pixel sums and AOVs), one batch's buffers, the scene
with its BVH and the estimator's own structures (`VisibilityEstimator.memory_estimate`: photons, kd-trees, look-ups); `check`
refuses a render that would not fit in the memory available now, naming what to lower.
"""
import resource
from pathlib import Path

import psutil

from .cases import N_CASES
from .errors import is_builtin, is_number

GIB = float(1 << 30)
ENV_PIXEL_BYTES = 170  # an environment map's sampling tables as they are built, per pixel (tracemalloc's peak)
KERNEL_BYTES = 80 << 20  # the machine code of every kernel, loaded by a process's first render
SLOT_BYTES = 3 * 3 * 8 + 4 + 1  # per shadow-ray slot: origin, direction, contribution, emitter, active
SEGMENT_BYTES = 2 * 3 * 8 + 8 + 4 + 8 + 8 + 8 + 4 + 4  # per segment: the query, the estimate and its counts
SAMPLE_BYTES = 400  # per camera sample of a batch: rays, hits, interactions, keys, cases
PIXEL_BYTES = 3 * 8 * 2 + 5 * 8 + 2 * 8 + 3 * 4 * 2  # film sums, counts, the AOV images and the output image
SPLAT_BYTES = 4 * 8  # per pixel of a splatting film: its weight sum and weighted variance
TRIANGLE_BYTES = 72 + 72 + 24 + 4 + 4 + 72 + 8 + 2 * 128  # scene arrays, BVH-order copy, ids, nodes
PARTS = ("film", "batch", "scene", "environment", "splat", "process", "kernels")  # what probvis counts itself


def estimate(scene, settings, estimator, batch_pixels, staged=True, splat_bytes=0):
    """Bytes by part (a dict) of rendering `scene` with `settings` and `estimator`; `staged`: its render may take
    the staged path, whose batches have shadow-ray slots and segments; `splat_bytes`: what a splatting film's
    chunk of per-pixel blocks takes (0 for a box filter)."""
    n_pix = scene.camera.width * scene.camera.height
    per_batch = batch_pixels * settings.spp
    parts = {
        "film": n_pix * (PIXEL_BYTES + 8 * sum(a.kind == "segment" for a in estimator.aovs)
                         + (scene.n_emitters * N_CASES * (4 + 8) if any(a.kind == "cases" for a in estimator.aovs)
                            else 0)
                         + (SPLAT_BYTES if splat_bytes else 0)),
        "batch": per_batch * (SAMPLE_BYTES + settings.shadow_rays * (SLOT_BYTES + SEGMENT_BYTES if staged else 0)),
        "scene": scene.n_triangles * TRIANGLE_BYTES,
        "environment": 0 if scene.environment is None else scene.environment.image[..., 0].size * ENV_PIXEL_BYTES,
        "splat": splat_bytes,
        "process": psutil.Process().memory_info().rss,  # what is already resident: Python, Numba, the scene
    }
    own = estimator.memory_estimate(scene, settings, per_batch)
    if not is_byte_counts(own):
        from .errors import ProbvisError

        cls = type(estimator)
        raise ProbvisError(f"visibility '{cls.name}' ({cls.__module__}.{cls.__qualname__}): memory_estimate() must "
                           f"return a dict of byte counts (whole numbers from 0 to 2**63: no machine holds more), "
                           f"got {own!r:.200}")
    clash = sorted(set(own) & set(PARTS))
    if clash:
        from .errors import ProbvisError

        cls = type(estimator)
        raise ProbvisError(f"visibility '{cls.name}' ({cls.__module__}.{cls.__qualname__}): memory_estimate() names "
                           f"{', '.join(clash)}, which probvis counts itself ({', '.join(PARTS)}): name the "
                           "estimator's own parts")
    if not is_builtin(type(estimator)):  # a plug-in's parts, named with it in an error
        own = {f"visibility '{estimator.name}': {k}": v for k, v in own.items()}
    parts.update(own)
    return parts


def is_byte_counts(value):
    """Whether `value` is what an estimator's `memory_estimate()` and `memory_bytes()` return: a dict of byte
    counts (numbers from 0 to 2^63)."""
    return isinstance(value, dict) and all(is_number(v) and 0 <= v < 2 ** 63 for v in value.values())


def available():
    """Bytes this process can still get now: the machine's available memory, or less under an address-space
    limit (`ulimit -v`, RLIMIT_AS), of which the process's mappings already take their part."""
    free = psutil.virtual_memory().available
    limit, _ = resource.getrlimit(resource.RLIMIT_AS)
    if limit == resource.RLIM_INFINITY:
        return free
    return max(0, min(free, limit - psutil.Process().memory_info().vms))


def peak_rss():
    """The process's peak resident set so far, in bytes."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


# what lowers each part of a render's estimate, named in `check`'s message (the film's: `render_hints`)
RENDER_HINTS = {"photons": "--photons", "lookups": "--neighbours or --shadow-rays", "batch": "--spp or --shadow-rays",
                "environment": "the environment map's size"}


def render_hints(scene):
    """`RENDER_HINTS` with the film's: -D res where the scene declares `res`, else its film's width and height."""
    file = f" in {Path(scene.source).name}" if scene.source else ""
    where = "-D res" if "res" in scene.parameters else f"the film's width and height{file}"
    return {**RENDER_HINTS, "film": f"the resolution ({where}, or resolution= in Python)"}


def check(parts, hints, estimator=None):
    """Refuse (ProbvisError) when the estimate exceeds the available memory; `hints` maps a part to the option
    that lowers it, and an estimator's own part (not in PARTS) is lowered by the options of `estimator` (its name)
    where `hints` does not name one."""
    from .errors import ProbvisError

    hints = {**{k: f"the options of visibility '{estimator}'" for k in parts if k not in PARTS and estimator}, **hints}

    need, have = sum(v for k, v in parts.items() if k not in ("process", "kernels")), available()
    if need > have:
        big = sorted(parts.items(), key=lambda kv: -kv[1])
        detail = ", ".join(f"{k} {v / GIB:.1f} GiB" for k, v in big if v >= 0.05 * need)
        lower = ", ".join(dict.fromkeys(hints[k] for k, v in big if k in hints and v >= 0.2 * need)) or "the settings"
        raise ProbvisError(f"this render needs about {need / GIB:.1f} GiB ({detail}) but {have / GIB:.1f} GiB are "
                           f"available: lower {lower}")
