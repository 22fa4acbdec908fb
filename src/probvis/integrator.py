"""Direct illumination, run stage by stage over batches of whole pixels (wavefront style):

    scene -> BVH (`accel`) and emitter sampler (`emitters`), once per render; the estimator's `prepare`;
    per batch: camera rays (`camera`) -> first hits (`accel`) -> surface interactions (`interaction`)
    -> the estimator's cases (`classify`) -> the render path -> film (`film`)

The render path is chosen once, after `prepare`, by the estimator (`VisibilityEstimator.render_path`): the
staged path makes the batch's shadow segments (`segments`) and asks the estimator's `evaluate`; exact
visibility takes the fused kernel (`fused_exact`: sample, trace and sum a shading point's segments while they
are in cache, the staged path's numbers bit for bit); an estimator with a kernel of its own renders the batch
itself (`shade`). This is Mitsuba 3's `direct` integrator with `bsdf_samples = 0`: each camera sample takes
`shadow_rays` emitter samples (emitter by power, triangle by area, uniform point) with a Lambertian BRDF.
"""
import os
import sys
import time
import warnings
from dataclasses import dataclass, field

import numba
import numpy as np
from threadpoolctl import threadpool_limits

from . import memory
from .accel import build_bvh
from .camera import camera_params, camera_rays
from .cases import CASE_MASK, CASE_UNKNOWN, N_CASES
from .emitters import build_emitter_sampler
from .errors import ProbvisError, checked_call, is_builtin, is_flag, is_path
from .film import Film, splat_chunk, splat_filter, warn_if_black
from .fused_exact import shade_exact
from .interaction import camera_hits, scene_arrays, surface_interactions
from .interrupts import deferred_interrupts
from .plugin_checks import (arrays_digest, check_accounts, check_unchanged, checked_cases, checked_fused,
                            checked_result, checked_settings, checked_shaded, checked_stats, plugin_errors)
from .render_stats import render_stats
from .scene import Scene, open_scene
from .scene.builtin import warm_up_scene
from .segments import SegmentBuffers, compact, sample_emitters, sample_radiance
from .settings import RenderSettings, whole_number
from .shading import ShadedBatch, ShadingBatch
from .visibility import RenderPath, ShadingPoints, ShadowQuery, VisibilityEstimator, estimator_class
from .warm_up import ensure_warm, is_warm, largest_mesh

TARGET_SLOTS = 1 << 18  # shadow-ray slots per staged batch (bounds memory, keeps progress and Ctrl-C prompt)
TARGET_LOOKUPS = 1 << 15  # at least this many (camera sample, emitter) pairs per batch of a kernel path


def render_memory(scene, settings, estimator):
    """Bytes by part (`memory.estimate`) a render with `estimator` (made, not prepared) will take."""
    staged = type(estimator).render_path is VisibilityEstimator.render_path  # may need the slot buffers
    rfilter = splat_filter(scene.camera, settings.filter_importance)
    with plugin_errors(type(estimator), "memory_estimate"):
        return memory.estimate(scene, settings, estimator, batch_pixels(scene, settings, staged), staged,
                               splat_chunk(rfilter, scene.camera.width)[1] if rfilter is not None else 0)


def batch_pixels(scene, settings, staged=True):
    """Whole pixels per batch. The staged path holds every shadow-ray slot of its batch: about TARGET_SLOTS of
    them. A kernel path (`staged=False`) holds per camera sample only its interaction and, per emitter, its
    look-up: at least TARGET_LOOKUPS of those, so that what a batch costs once (a kd-tree query's threads, a
    kernel's launch) spreads over many points and nearby points share more look-ups."""
    n_pix = scene.camera.width * scene.camera.height
    samples = TARGET_SLOTS // settings.shadow_rays
    if not staged:
        samples = max(samples, TARGET_LOOKUPS // max(1, scene.n_emitters))
    return max(1, min(n_pix, samples // settings.spp))


@dataclass
class RenderResult:
    """`image` is (height, width, 3) float64 radiance; `aovs` holds per-pixel images such as test counts."""

    image: np.ndarray
    stats: dict
    aovs: dict = field(default_factory=dict)


class Integrator:
    """Mitsuba's `direct` integrator on one scene: the structures of one render and the front end of a batch
    (camera rays, their first hits, surface interactions). An estimator's `prepare` receives it: a kernel of its
    own takes `scene_arrays`, and a pilot renders through `shading_batch` and `shade_exact`, or traces the
    segments `shadow_query` makes."""

    def __init__(self, scene, bvh, emitters, filter_importance=False):
        self.scene, self.bvh, self.emitters = scene, bvh, emitters
        self.camera = camera_params(scene.camera, filter_importance)
        self.scene_arrays, self.surface = scene_arrays(scene)

    def shading_batch(self, pixels, spp, shadow_rays, seed):
        """The `ShadingBatch` of image pixels `pixels` (row-major, int64), every case unknown."""
        org, dirs, tmin, tmax, keys, film_xy = camera_rays(self.camera, spp, seed, pixels)
        prim, _, b1, b2, cam_node, cam_tri = camera_hits(self.bvh, self.scene.tri_emitter, self.scene.hide_emitters,
                                                         org, dirs, tmin, tmax)
        its = surface_interactions(self.scene_arrays, self.surface, self.emitters.arrays, prim, b1, b2, dirs)
        cases = np.full((len(prim), self.scene.n_emitters), CASE_UNKNOWN, np.int8)
        return ShadingBatch(pixels, spp, shadow_rays, prim, its.emitted, its.position, its.normal, its.material,
                            its.albedo, cases, keys, cam_node, cam_tri, film_xy)

    def shade_exact(self, batch):
        """The fused exact-visibility kernel's `ShadedBatch`."""
        return ShadedBatch(*shade_exact(self.scene_arrays, self.emitters.arrays, self.bvh.arrays, batch))

    def shadow_query(self, batch):
        """The `ShadowQuery` of a `ShadingBatch`'s shadow segments, exactly as the staged path makes them: what a
        pilot traces to learn visibility (fresh buffers; the render's own are reused by its `StagedPath`)."""
        n_slots = len(batch.keys) * batch.shadow_rays
        return self.segments(batch, SegmentBuffers(n_slots))[0]

    def segments(self, batch, buffers):
        """The batch's shadow segments in `buffers`: (`ShadowQuery`, emitted and analytic radiance per camera
        sample, the `ShadowSlots`, the dense offsets of each camera sample's segments)."""
        slots = buffers.slots(len(batch.keys) * batch.shadow_rays)
        emitted = batch.emitted + sample_emitters(self.scene_arrays, self.emitters.arrays, batch, slots,
                                                  numba.get_num_threads())
        offsets = compact(batch, slots, buffers.dense)
        seg = buffers.segments(int(offsets[-1]))
        query = ShadowQuery(origin=seg.origin, direction=seg.direction, tmax=seg.tmax, point=seg.point,
                            emitter=seg.emitter, key=seg.key, weight=seg.weight)
        return query, emitted, slots, offsets


class StagedPath:
    """The batch's shadow segments (`segments`), the estimator's `evaluate` on them, each sample's radiance."""

    def __init__(self, integrator, estimator, n_slots):
        self.integrator, self.estimator = integrator, estimator
        self.buffers = SegmentBuffers(n_slots)

    def __call__(self, batch):
        query, emitted, slots, offsets = self.integrator.segments(batch, self.buffers)
        res = checked_result(self.estimator, self.estimator.evaluate(query), len(query.tmax))
        radiance, counts, segments = sample_radiance(batch, emitted, slots, offsets, res.value, res.node_tests,
                                                     res.triangle_tests)
        pixel = query.point // batch.spp
        aovs = {name: np.bincount(pixel, weights=v, minlength=len(batch.pixel)) / batch.spp
                for name, v in res.aovs.items()}
        return ShadedBatch(radiance, counts, segments, aovs)


def make_path(integrator, estimator, path, n_slots):
    """The render path `path` (a `RenderPath`, the estimator's choice after `prepare`) as a function of a
    `ShadingBatch` to its `ShadedBatch`."""
    if path == RenderPath.FUSED_EXACT:
        own = is_builtin(type(estimator))
        return integrator.shade_exact if own else checked_fused(integrator, estimator)
    if path == RenderPath.OWN_KERNEL:
        if is_builtin(type(estimator)):
            return estimator.shade
        return lambda batch: checked_shaded(estimator, estimator.shade(batch), batch)
    if path == RenderPath.STAGED:
        return StagedPath(integrator, estimator, n_slots)
    raise ProbvisError(f"visibility '{estimator.name}': render_path() returned {path!r}, not a RenderPath")


@dataclass
class _Pass:
    """What one pass over the image produced, for the stats."""

    film: Film
    bvh: object
    path: RenderPath
    shadow_rays: int
    camera_hits: int
    cases: list
    seconds: dict


def render_pass(scene, settings, estimator, progress=False):
    """Build the BVH, prepare the estimator and render every batch of pixels into a `Film`."""
    t0 = time.perf_counter()
    bvh = build_bvh(scene.triangles)
    emitters = build_emitter_sampler(scene)
    integrator = Integrator(scene, bvh, emitters, settings.filter_importance)
    t1 = time.perf_counter()
    own = is_builtin(type(estimator))
    watched = None if own else arrays_digest(integrator)
    estimator.prepare(scene if own else scene.read_only(), bvh, emitters, settings, integrator)
    t2 = time.perf_counter()
    n_pix_total = scene.camera.width * scene.camera.height
    spp, n_shadow = settings.spp, settings.shadow_rays
    chosen = estimator.render_path()
    per_batch = batch_pixels(scene, settings, chosen == RenderPath.STAGED)
    path = make_path(integrator, estimator, chosen, per_batch * spp * n_shadow)
    film = Film(scene.camera.width, scene.camera.height, spp, scene.n_emitters,
                [a.name for a in estimator.aovs if a.kind == "segment"],
                splat_filter(scene.camera, settings.filter_importance))
    n_segments, camera_hits, case_totals = 0, 0, [0] * N_CASES
    bar = None
    if progress and sys.stderr.isatty():
        from tqdm import tqdm

        bar = tqdm(total=n_pix_total, unit="px", unit_scale=True, desc=f"render {scene.name}", leave=False)
    with deferred_interrupts() as check_interrupt:  # Ctrl-C stops between batches, not inside a kernel
        try:
            for p0 in range(0, n_pix_total, per_batch):
                check_interrupt()
                batch = integrator.shading_batch(np.arange(p0, min(n_pix_total, p0 + per_batch)), spp, n_shadow,
                                                 settings.seed)
                shaded = batch.material >= 0
                cases = estimator.classify(ShadingPoints(batch.position, batch.normal,
                                                         np.where(shaded, batch.triangle, -1), batch.keys,
                                                         batch.albedo))
                if cases is not None:
                    batch = batch._replace(cases=checked_cases(estimator, cases, batch.cases))
                    film.add_cases(batch)
                    counted = batch.cases[shaded] & CASE_MASK
                    for c in range(N_CASES):
                        case_totals[c] += int((counted == c).sum())
                result = path(batch)
                film.add(batch, result)
                n_segments += int(result.segments.sum())
                camera_hits += int((batch.triangle >= 0).sum())
                if bar is not None:
                    bar.update(len(batch.pixel))
        finally:
            if bar is not None:
                bar.close()
    seconds = {"bvh": t1 - t0, "prepare": t2 - t1, "render": time.perf_counter() - t2}
    if watched is not None:
        check_unchanged(estimator, integrator, watched)
    return _Pass(film, bvh, chosen, n_segments, camera_hits,
                 case_totals if film.case_counts is not None else None, seconds)


def warm_up_render(cls, options, largest=None):
    """Renders of `cls` on the warm-up scene with each of `cls.warm_ups(options, largest)`: every kernel a render
    with `options` runs, the BVH's stats' too (silent: its warnings would be about that scene); see `warm_up`."""
    with warnings.catch_warnings(action="ignore"):
        for opts in cls.warm_ups(options, largest):
            render_pass(warm_up_scene(), RenderSettings(spp=1, shadow_rays=2), cls(**opts)).bvh.stats()


def _check_arguments(scene, settings, resolution, defines, options, numbers, flags):
    """The API's arguments of the wrong type, as one ProbvisError naming the argument (ranges: where used)."""
    if not (isinstance(scene, Scene) or is_path(scene)):
        raise ProbvisError(f"scene must be a Scene, a scene file path or a built-in name, got {type(scene).__name__}")
    if settings is not None and not isinstance(settings, RenderSettings):
        raise ProbvisError(f"settings must be a RenderSettings, got {type(settings).__name__}")
    if resolution is not None and not (isinstance(resolution, (tuple, list, np.ndarray)) and len(resolution) == 2
                                       and all(whole_number(v) for v in list(resolution))):
        raise ProbvisError(f"resolution must be (width, height), two whole numbers, got {resolution!r}")
    for name, value in (("defines", defines), ("visibility_options", options)):
        if value is not None and not isinstance(value, dict):
            raise ProbvisError(f"{name} must be a dict of name: value, got {type(value).__name__}")
        if value is not None and not all(isinstance(k, str) for k in value):
            raise ProbvisError(f"{name} must be a dict with names (strings) as keys, got {sorted(map(repr, value))}")
    for name, value in flags.items():
        if not is_flag(value) and value is not None:
            raise ProbvisError(f"{name} must be True or False, got {value!r}")
    for name, value in numbers.items():
        if value is not None and not whole_number(value):
            raise ProbvisError(f"{name} must be a whole number, got {value!r} (a {type(value).__name__})")


@checked_call
def render(scene, settings=None, *, spp=None, shadow_rays=None, seed=None, threads=None, resolution=None,
           visibility="exact", visibility_options=None, defines=None, strict=False, progress=False,
           clamp_negative=False, filter_importance=None):
    """Render `scene` (a `Scene`, a Mitsuba XML path or a built-in name) with direct illumination.

    Settings start from the scene's own (`Scene.defaults`: its sampler and integrator) or `settings` (a
    `RenderSettings`); `spp`, `shadow_rays` (emitter samples per camera sample), `seed` and `threads` replace
    single ones, and `resolution` (width, height) the film's size. The film splats each camera sample over the
    pixels its reconstruction filter covers, as Mitsuba's; `filter_importance=True` draws the samples from the
    filter instead, one pixel each (noisier, but each pixel's expectation is exactly the filtered radiance).
    `defines` are `<default>` overrides for loading the scene (like Mitsuba's `-D`); `strict` makes approximated
    appearance an error. `visibility` is an estimator name (built-in, installed, or
    `module:Class`), class or instance, with `visibility_options` for a name or class. `clamp_negative` sets
    negative pixels (from probabilistic visibility) to zero: biased, the image gets too bright on average; the
    stats report by how much. `progress` says so on stderr when the kernels compile (with a bar on a
    terminal) and shows a progress bar over the batches on a terminal. Returns a `RenderResult` whose `.stats`
    is JSON-serialisable.
    """
    t_start, cpu_start = time.perf_counter(), time.process_time()
    _check_arguments(scene, settings, resolution, defines, visibility_options,
                     dict(spp=spp, shadow_rays=shadow_rays, seed=seed, threads=threads),
                     dict(strict=strict, progress=progress, clamp_negative=clamp_negative))
    early = threads if threads is not None else getattr(settings, "threads", None)
    if early is not None and 1 <= early <= numba.config.NUMBA_NUM_THREADS:  # loading keeps to the budget too
        numba.set_num_threads(early)
    if resolution is not None and "res" in (defines or {}):  # the film's size is set once, as in a study
        raise ProbvisError("resolution= and the scene parameter res (defines) both set the film's size: give one")
    if not isinstance(scene, Scene):
        scene = open_scene(scene, defines or {}, strict)
    elif defines:
        raise ProbvisError(f"scene parameters {sorted(defines)} apply only when loading a scene from a file")
    elif strict:
        raise ProbvisError("strict applies when a scene is loaded: give it to load_scene(path, strict=True), or "
                           "give render() the path")
    else:
        scene.validate()  # a Scene may have been changed since it was loaded
    load_seconds = time.perf_counter() - t_start
    if resolution is not None:
        scene = scene.with_resolution(*(int(v) for v in resolution))
    settings = (settings or scene.defaults).replace(spp=spp, shadow_rays=shadow_rays, seed=seed, threads=threads,
                                                    filter_importance=filter_importance).check_budget()
    if settings.threads is not None and settings.threads > numba.config.NUMBA_NUM_THREADS:
        n = numba.config.NUMBA_NUM_THREADS
        why = f"NUMBA_NUM_THREADS={n} in the environment" if os.environ.get("NUMBA_NUM_THREADS") else f"{n} cores"
        raise ProbvisError(f"threads must be between 1 and {n} ({why}), got {settings.threads}")
    threads = settings.threads or numba.config.NUMBA_NUM_THREADS
    numba.set_num_threads(threads)
    if isinstance(visibility, VisibilityEstimator):
        if visibility_options:
            raise ProbvisError("visibility_options apply to an estimator name or class, not to an instance")
        estimator, options = visibility, checked_settings(visibility)
    else:
        options = dict(visibility_options or {})
        cls = estimator_class(visibility)
        with plugin_errors(cls, "__init__"):
            estimator = cls(**options)
    need = render_memory(scene, settings, estimator)
    largest = largest_mesh(scene)
    if not is_warm(type(estimator), options, largest):
        need["kernels"] = memory.KERNEL_BYTES  # loading (or compiling) the kernels comes after the estimate
    memory.check(need, memory.render_hints(scene), estimator.name)
    with threadpool_limits(limits=threads):  # one budget: BLAS and OpenMP pools get no more than Numba
        with plugin_errors(type(estimator), "the render (prepare, classify, evaluate or shade)"):
            cpu_compile = time.process_time()
            compile_seconds = ensure_warm(warm_up_render, type(estimator), options, largest, progress)
            cpu_render = time.process_time()
            cpu_compile = cpu_render - cpu_compile
            result = render_pass(scene, settings, estimator, progress)
    image = result.film.developed()
    warn_if_black(image)
    negative = image < 0
    clamp = {"negative_pixel_share": float(negative.any(axis=-1).mean()),
             "negative_value_share": float(negative.mean()), "clamped": bool(clamp_negative)}
    if clamp_negative:
        clamped = np.maximum(image, 0.0)
        clamp["mean_bias"] = [float(x) for x in (clamped - image).reshape(-1, 3).mean(axis=0)]
        image = clamped
    seconds = {"total": time.perf_counter() - t_start, "load": load_seconds, "compile": compile_seconds,
               **result.seconds, "cpu_total": time.process_time() - cpu_start, "cpu_compile": cpu_compile,
               "cpu_render": time.process_time() - cpu_render}
    mem = {"estimated_bytes": int(sum(need.values())), "estimate": {k: int(v) for k, v in need.items()},
           "process_peak_rss_bytes": memory.peak_rss()}
    with plugin_errors(type(estimator), "stats"):
        stats = render_stats(scene, settings, estimator, result, image, clamp, seconds, mem)
    if not is_builtin(type(estimator)):
        stats["estimator"] = checked_stats(type(estimator), stats["estimator"])
        check_accounts(type(estimator), stats)
    return RenderResult(image, stats, result.film.aovs())
