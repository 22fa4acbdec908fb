"""Direct illumination, run stage by stage over batches of whole pixels (wavefront style):

    camera rays (`camera`) -> surface interactions (`interaction`) -> emitter samples (`emitters`)
    -> shadow segments (`segments`) -> visibility (`visibility`, the estimator) -> film (`film`)

Estimators that declare `fused_any_hit` (exact visibility) take a fused last three stages instead
(`fused_exact`: sample, trace and sum a shading point's segments while they are in cache), with the staged
path's numbers bit for bit; estimators that declare `fused_shade` render whole pixels through their own fused
kernel (`VisibilityEstimator.shade`). This is Mitsuba 3's `direct` integrator with `bsdf_samples = 0`: each camera sample
takes `shadow_rays` emitter samples (emitter by power, triangle by area, uniform point) with a Lambertian BRDF.
"""
import sys
import time
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path

import numba
import numpy as np
from threadpoolctl import threadpool_limits

from . import memory
from .accel import build_bvh, nearest_hits
from .camera import camera_params, camera_rays
from .cases import CASE_MASK, CASE_UNKNOWN, N_CASES
from .emitters import add_environment, build_emitter_sampler, sample_emitters
from .errors import ProbvisError
from .film import Film, accumulate
from .fused_exact import shade_exact
from .interaction import scene_arrays, surface_interactions
from .interrupts import deferred_interrupts
from .render_stats import render_stats
from .scene import Scene, load_scene
from .scene.scene import EMITTER_ENVIRONMENT
from .segments import SegmentBuffers, compact
from .settings import RenderSettings
from .visibility import ShadingPoints, ShadowQuery, VisibilityEstimator, estimator_class

TARGET_SLOTS = 1 << 18  # shadow-ray slots per batch (bounds memory, keeps progress and Ctrl-C prompt)
COMPILE_TIME = "1-3 minutes"  # what the first run's kernel compilation takes on 2 cores (60-150 s measured)
MEMORY_HINTS = {"film": "the resolution (-D res, resolution=)", "photons": "--photons",
                "lookups": "--neighbours or --shadow-rays", "batch": "--spp or --shadow-rays"}


def batch_pixels(scene, settings):
    """Whole pixels per batch: about TARGET_SLOTS shadow-ray slots."""
    n_pix = scene.camera.width * scene.camera.height
    return max(1, min(n_pix, TARGET_SLOTS // (settings.spp * settings.shadow_rays)))


@dataclass
class RenderResult:
    """`image` is (height, width, 3) float64 radiance; `aovs` holds per-pixel images such as test counts."""

    image: np.ndarray
    stats: dict
    aovs: dict = field(default_factory=dict)


@dataclass
class _Pass:
    """What one pass over the image produced, for the stats."""

    film: Film
    bvh: object
    shadow_rays: int
    camera_hits: int
    cases: list
    seconds: dict


def render_pass(scene, settings, estimator, progress=False):
    """Build the BVH, prepare the estimator and render every batch of pixels into a `Film`."""
    t0 = time.perf_counter()
    bvh = build_bvh(scene.triangles)
    emitters = build_emitter_sampler(scene)
    t1 = time.perf_counter()
    estimator.prepare(scene, bvh, emitters, settings)
    t2 = time.perf_counter()

    cam = camera_params(scene.camera)
    geom, textures = scene_arrays(scene)
    es = emitters.arrays
    env_scale = scene.emitter_radiance[scene.emitter_kind == EMITTER_ENVIRONMENT]  # what camera rays that miss see
    width, height = scene.camera.width, scene.camera.height
    n_pix_total = width * height
    spp, n_shadow = settings.spp, settings.shadow_rays
    per_batch = batch_pixels(scene, settings)
    # fused_any_hit is checked per batch, after `classify`: an estimator with its own kernel may settle it late
    staged = not (estimator.fused_any_hit or estimator.fused_shade)
    buffers = SegmentBuffers(per_batch * spp * n_shadow) if staged else None
    film = Film(width, height, spp, scene.n_emitters, [a.name for a in estimator.aovs if a.kind == "segment"])
    n_segments, camera_hits, case_totals = 0, 0, [0] * N_CASES
    bar = None
    if progress and sys.stderr.isatty():
        from tqdm import tqdm

        bar = tqdm(total=n_pix_total, unit="px", unit_scale=True, desc=f"render {scene.name}", leave=False)
    with deferred_interrupts() as check_interrupt:  # Ctrl-C stops between batches, not inside a kernel
        try:
            for p0 in range(0, n_pix_total, per_batch):
                check_interrupt()
                p1 = min(n_pix_total, p0 + per_batch)
                org, dirs, tmin, tmax, keys = camera_rays(cam, spp, settings.seed, np.arange(p0, p1))
                prim, _, b1, b2, cam_node, cam_tri = nearest_hits(bvh, org, dirs, tmin, tmax)
                its = surface_interactions(geom, textures, prim, b1, b2, dirs)
                for scale in env_scale:
                    add_environment(its.emitted, prim, dirs, es, scale)
                cases = estimator.classify(ShadingPoints(its.position, its.normal,
                                                         np.where(its.material >= 0, prim, -1), keys))
                if cases is None:
                    cases = np.full((len(prim), scene.n_emitters), CASE_UNKNOWN, np.int8)
                else:
                    film.add_cases(p0, p1, cases)
                    shaded = cases[its.material >= 0] & CASE_MASK
                    for c in range(N_CASES):
                        case_totals[c] += int((shaded == c).sum())
                if estimator.fused_any_hit:
                    img, m2, cnt, n_seg = shade_exact(geom, es, bvh.arrays, prim, its.position, its.normal,
                                                      its.material, its.albedo, cases, keys, its.emitted, cam_node,
                                                      cam_tri, spp, n_shadow, p1 - p0)
                    n_q = int(n_seg.sum())
                elif estimator.fused_shade:
                    img, m2, cnt, n_seg = estimator.shade(geom, es, its, cases, keys, cam_node, cam_tri, spp,
                                                          n_shadow, p1 - p0, p0)
                    n_q = int(n_seg.sum())
                else:
                    s_org, s_dir, contrib, s_emit, active = buffers.slots(len(prim) * n_shadow)
                    emitted = its.emitted + sample_emitters(geom, es, prim, its.position, its.normal, its.material,
                                                            its.albedo, cases, keys, n_shadow, s_org, s_dir, contrib,
                                                            s_emit, active)
                    offsets = compact(active, s_org, s_dir, s_emit, contrib, keys, n_shadow, *buffers.segments())
                    n_q = int(offsets[-1])
                    query = ShadowQuery(origin=buffers.org[:n_q], direction=buffers.dirs[:n_q],
                                        tmax=buffers.tmax[:n_q], point=buffers.point[:n_q],
                                        emitter=buffers.emit[:n_q], key=buffers.key[:n_q],
                                        weight=buffers.weight[:n_q])
                    res = estimator.evaluate(query)
                    img, m2, cnt = accumulate(emitted, contrib, active, offsets, res.value, cam_node, cam_tri,
                                              res.node_tests, res.triangle_tests, spp, n_shadow, p1 - p0)
                    if res.aovs:
                        film.add_segment_aovs(p0, p1, query.point, res.aovs)
                film.store(p0, p1, img, m2, cnt)
                n_segments += n_q
                camera_hits += int((prim >= 0).sum())
                if bar is not None:
                    bar.update(p1 - p0)
        finally:
            if bar is not None:
                bar.close()
    seconds = {"bvh": t1 - t0, "prepare": t2 - t1, "render": time.perf_counter() - t2}
    return _Pass(film, bvh, n_segments, camera_hits, case_totals if film.case_counts is not None else None, seconds)


_warmed = set()


def _cold_cache():
    """Whether Numba's on-disk cache lacks the kernels (a first run, or a changed probvis)."""
    return not any((Path(__file__).parent / "__pycache__").glob("fused_exact.shade_exact-*.nbi"))


class _CompileProgress:
    """A progress bar over Numba's compile events, for the first run's warm-up."""

    def __init__(self):
        from numba.core import event
        from tqdm import tqdm

        self.bar = tqdm(desc="compiling kernels", unit=" kernels", leave=False)
        self.listener = event.install_listener("numba:compile", self)

    def on_start(self, ev):
        pass

    def on_end(self, ev):
        self.bar.update(1)

    def __enter__(self):
        self.listener.__enter__()
        return self

    def __exit__(self, *exc):
        self.listener.__exit__(*exc)
        self.bar.close()


def _warm_up(cls, options, progress):
    """Compile (or load from Numba's cache) every kernel of the pipeline on a tiny scene; returns seconds."""
    key = (cls, repr(sorted(options.items())))
    if key in _warmed:
        return 0.0
    from .scene.builtin import quad_shadow

    t0 = time.perf_counter()
    cold = progress and _cold_cache()
    if cold:
        print(f"probvis: compiling kernels (first run only, about {COMPILE_TIME} on 2 cores)", file=sys.stderr,
              flush=True)
    with _CompileProgress() if cold and sys.stderr.isatty() else nullcontext():
        render_pass(quad_shadow(res=4), RenderSettings(spp=1, shadow_rays=2), cls(**options))
    _warmed.add(key)
    return time.perf_counter() - t0


def render(scene, settings=None, *, spp=None, shadow_rays=None, seed=None, threads=None, resolution=None,
           visibility="exact", visibility_options=None, defines=None, strict=False, progress=False,
           clamp_negative=False):
    """Render `scene` (a `Scene`, a Mitsuba XML path or a built-in name) with direct illumination.

    Settings start from the scene's own (`Scene.defaults`: its sampler and integrator) or `settings` (a
    `RenderSettings`); `spp`, `shadow_rays` (emitter samples per camera sample), `seed` and `threads` replace
    single ones, and `resolution` (width, height) the film's size. `defines` are `<default>` overrides for
    loading the scene (like Mitsuba's `-D`); `strict` makes approximated appearance an error. `visibility` is an estimator name (built-in, installed, or
    `module:Class`), class or instance, with `visibility_options` for a name or class. `clamp_negative` sets
    negative pixels (from probabilistic visibility) to zero: biased, the image gets too bright on average; the
    stats report by how much. `progress` says so on stderr when the kernels compile (with a bar on a
    terminal) and shows a progress bar over the batches on a terminal. Returns a `RenderResult` whose `.stats`
    is JSON-serialisable.
    """
    t_start, cpu_start = time.perf_counter(), time.process_time()
    if not isinstance(scene, Scene):
        scene = load_scene(scene, strict, **(defines or {}))
    elif defines:
        raise ProbvisError(f"scene parameters {sorted(defines)} apply only when loading a scene from a file")
    load_seconds = time.perf_counter() - t_start
    if resolution is not None:
        scene = scene.with_resolution(*resolution)
    settings = (settings or scene.defaults).replace(spp=spp, shadow_rays=shadow_rays, seed=seed, threads=threads)
    if settings.threads is not None and settings.threads > numba.config.NUMBA_NUM_THREADS:
        raise ProbvisError(f"threads must be between 1 and {numba.config.NUMBA_NUM_THREADS}, got {settings.threads}")
    threads = settings.threads or numba.config.NUMBA_NUM_THREADS
    numba.set_num_threads(threads)
    if isinstance(visibility, VisibilityEstimator):
        if visibility_options:
            raise ProbvisError("visibility_options apply to an estimator name or class, not to an instance")
        estimator, options = visibility, visibility.settings()
    else:
        options = dict(visibility_options or {})
        estimator = estimator_class(visibility)(**options)
    need = memory.estimate(scene, settings, estimator, batch_pixels(scene, settings))
    if (type(estimator), repr(sorted(options.items()))) not in _warmed:
        need["kernels"] = memory.KERNEL_BYTES  # loading (or compiling) the kernels comes after the estimate
    memory.check(need, MEMORY_HINTS)
    with threadpool_limits(limits=threads):  # one budget: BLAS and OpenMP pools get no more than Numba
        cpu_compile = time.process_time()
        compile_seconds = _warm_up(type(estimator), options, progress)
        cpu_render = time.process_time()
        cpu_compile = cpu_render - cpu_compile
        result = render_pass(scene, settings, estimator, progress)
    image = result.film.developed()
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
    stats = render_stats(scene, settings, estimator, result, image, clamp, seconds, mem)
    return RenderResult(image, stats, result.film.aovs())
