"""The plan of proxy visibility with `q=auto`: per emitter and film region, exact visibility alone or the proxy
with its own q, chosen from a pilot to minimise variance × cost (the 2014 paper's choice among the original
geometry, the proxy and the correction, made per region; derived in docs/decisions.md, "Efficiency-aware q").

The pilot renders a grid of the image's own pixels, one sample each, for two independent sets of camera
samples: exact visibility through the integrator's fused kernel, and the proxy kernel with no exact test and
with every segment tested both ways, without the shells and, if there are any, with them. From those it takes
the costs (relative to exact visibility), each region's variance and mismatch energy, and plans both
configurations; the render takes the one whose plan predicts more. Its first stage, exact visibility on the
first set and on a single sample, predicts the render's seconds and the pilot's: where the pilot would cost more
than PILOT_BUDGET of the render, nothing else is run or built, and exact visibility renders.
"""
import time
from dataclasses import dataclass

import numba
import numpy as np

from ..color import LUMINANCE
from .. import disk_cache
from ..settings import MAX_SEED
from ..shells import ShellTests
from .base import CASE_UNKNOWN
from .proxy_kernel import N_SUMS, SUM_BOTH, SUM_INV_P, SUM_MISMATCH, SUM_MISMATCH_W, SUM_W, SUM_WV, Correction

PILOT_RESOLUTION = 64  # the pilot's pixels along the image's longer side: up to 4,096 camera samples,
PILOT_SHARE = 1 / 300  # and at most this share of the render's camera samples per kernel run
PILOT_BUDGET = 0.03  # the pilot runs only if its predicted seconds are at most this share of the render's
PILOT_SETS = 2  # independent sets of pilot camera samples: their differences give the variance; each kernel
# runs on both and the faster time is kept (the first call may load or compile)
REGIONS = 8  # q per emitter in REGIONS x REGIONS tiles of the film
SHRINK = 256  # a region's mismatch energy and variance are shrunk toward its emitter's by this many segments' worth
PILOT_SALT = 0x50524F5859  # mixed into its seed, apart from the render's samples
Q_MIN = 0.02  # a region's q is never below this (a segment's, `segment_q`, never below a tenth of its region's)
PLAN_VERSION = 2  # of the cached decision's record (`Decision`)
PREDICTED = ("render_seconds", "pilot_seconds")  # the probe's predictions, in seconds (stored)
GAIN_MARGIN = 1.1  # proxies are used where the predicted gain exceeds this: a small view flatters them
SHELL_MARGIN = 1.05  # shells are kept where their plan predicts this much more than the plan without them


@dataclass
class Plan:
    """What the pilot chose and measured."""

    exact: np.ndarray  # (regions, emitters) bool: exact visibility alone
    q: np.ndarray  # (regions, emitters) probability of the exact test where the proxy is used
    gain: np.ndarray  # (emitters,) predicted efficiency gain over exact visibility (NaN: nothing measured)
    shells: ShellTests  # the configuration chosen (the shells, or none)
    shells_dropped: bool  # shells were built but the plan without them predicts more
    weight: np.ndarray = None  # (emitters,) the weight at which a segment takes its region's q (`segment_q`)
    costs: tuple = None  # (ρ, e): the proxy path's cost without and the extra exact test's, relative to exact
    camera_cost: float = None  # κ: the camera rays' cost, relative to the same
    sums: np.ndarray = None  # (emitters, N_SUMS) what the pilot measured
    segments: int = 0  # pilot segments measured both ways


@dataclass
class Decision:
    """What `q=auto` decided before the render, cached on disk under `decision_key`: the meshes that get proxies
    and shells (by their first triangle), the plan (None: exact visibility everywhere, the pilot not run or
    nothing to plan; its `shells` are not stored but built again from `shell_meshes`), the probe's predictions
    and whether the pilot ran; `cached`: read from the cache."""

    proxy_meshes: tuple
    shell_meshes: tuple
    plan: Plan = None
    predicted: dict = None
    pilot_ran: bool = False
    cached: bool = False

    def store(self, key):
        out = {"proxy_meshes": np.array(self.proxy_meshes, np.int64),
               "shell_meshes": np.array(self.shell_meshes, np.int64),
               "predicted": np.array([self.predicted[k] for k in PREDICTED] if self.predicted else [], float),
               "pilot_ran": np.array([self.pilot_ran], np.int64)}
        if self.plan is not None:
            p = self.plan
            out.update(exact=p.exact, q=p.q, gain=np.nan_to_num(p.gain, nan=-1.0), weight=p.weight, sums=p.sums,
                       costs=np.array(p.costs if p.costs is not None else [], float),
                       camera_cost=np.array([] if p.camera_cost is None else [p.camera_cost], float),
                       counts=np.array([p.segments, p.shells_dropped], np.int64))
        disk_cache.store("plans", key, out)

    @classmethod
    def load(cls, key, n_emitters):
        """The record `store` stored under `key`, or None (none, damaged or foreign)."""
        e, r = n_emitters, REGIONS * REGIONS
        base = {"proxy_meshes": ((None,), "i"), "shell_meshes": ((None,), "i"), "predicted": ((None,), "f"),
                "pilot_ran": ((1,), "i")}
        a = disk_cache.load("plans", key, base)
        if a is None or len(a["predicted"]) not in (0, len(PREDICTED)):
            return None
        predicted = None
        if len(a["predicted"]):
            predicted = dict(zip(PREDICTED, map(float, a["predicted"])))
            predicted["budget_seconds"] = PILOT_BUDGET * predicted["render_seconds"]
        meshes = tuple(map(int, a["proxy_meshes"])), tuple(map(int, a["shell_meshes"]))
        if "exact" not in a:
            return cls(*meshes, None, predicted, bool(a["pilot_ran"][0]))
        planned = {"exact": ((r, e), "b"), "q": ((r, e), "f"), "gain": ((e,), "f"), "weight": ((e,), "f"),
                   "sums": ((e, N_SUMS), "f"), "costs": ((None,), "f"), "camera_cost": ((None,), "f"),
                   "counts": ((2,), "i")}
        if not disk_cache.fits(a, planned) or len(a["costs"]) not in (0, 2) or len(a["camera_cost"]) > 1:
            return None
        a = {k: v.astype(np.float64) if v.dtype.kind == "f" else v for k, v in a.items()}
        if not (np.all((a["q"] > 0) & (a["q"] <= 1)) and np.all(a["weight"] >= 0) and np.all(a["costs"] > 0)
                and np.all(a["camera_cost"] >= 0) and a["counts"].min() >= 0):
            return None  # values no pilot makes: q = 0 would leave the proxy's error uncorrected
        segments, dropped = (int(x) for x in a["counts"])
        plan = Plan(a["exact"], a["q"], np.where(a["gain"] < 0, np.nan, a["gain"]), None, bool(dropped), a["weight"],
                    tuple(map(float, a["costs"])) or None,
                    float(a["camera_cost"][0]) if len(a["camera_cost"]) else None, a["sums"], segments)
        return cls(*meshes, plan, predicted, bool(a["pilot_ran"][0]))



def decision_key(integrator, settings, options):
    """The cache key of a `Decision`: XXH3 of the scene as the kernels see it (geometry, materials, emitters),
    the view, the samples, the threads and the estimator's options; not the seed (the pilot draws apart from
    the render's samples) nor textures' images (a plan only weighs cost against variance: any plan keeps the
    image unbiased, so a key that misses an edit costs efficiency, never correctness)."""
    sa, cam = integrator.scene_arrays, integrator.camera
    scene = [sa.triangles, sa.tri_material, sa.tri_emitter, sa.reflectance, sa.twosided, sa.emitter_radiance,
             sa.material_texture]
    view = [np.asarray(x, float).ravel() for x in cam]
    label = (f"proxy plan v{PLAN_VERSION} budget {PILOT_BUDGET} spp {settings.spp} rays {settings.shadow_rays} "
             f"threads {numba.get_num_threads()} hide {integrator.scene.hide_emitters} {sorted(options.items())}")
    return disk_cache.content_key(label, *scene, *integrator.emitters.arrays, *view)


def allocate(n, variance, mismatch, rho, exact=1.0, base=1.0, rounds=20, scaled=None):
    """Per region (arrays over regions of one emitter: segments, exact visibility's variance of the region's sum
    over its camera samples, mismatch energy) whether to use the proxy and its q, minimising total variance x
    total cost, with costs per segment `base` for exact visibility and `rho` + `exact` q for the proxy; and the
    predicted gain over exact visibility, (Σ V) base n / (variance x cost).

    `scaled` = (mismatch', n'): where each segment's q is the region's q times its weight over a reference
    weight (`proxy_kernel.segment_q`), the correction adds mismatch' / q instead of mismatch / q (mismatch' =
    Σ (V - V_P)² w w_ref) and costs exact q n' (n' = Σ w / w_ref) instead of exact q n."""
    n, variance, mismatch = (np.asarray(x, float) for x in (n, variance, mismatch))
    mismatch_q, n_q = (mismatch, n) if scaled is None else (np.asarray(x, float) for x in scaled)
    total_v, total_n = variance.sum(), n.sum()
    if total_v <= 0 or total_n <= 0:
        return np.zeros(len(n), bool), np.ones(len(n)), 1.0
    lam = total_v / (base * total_n)
    for _ in range(rounds):
        with np.errstate(divide="ignore", invalid="ignore"):
            q = np.clip(np.sqrt(np.where(n_q > 0, mismatch_q / (lam * exact * n_q), 1.0)), Q_MIN, 1.0)
        # the correction adds Σ (V - V_P)² w² (1/q_s - 1) >= 0 with each segment's q_s = q w / w_ref: never less
        # than nothing, although the unclipped q_s above 1 of heavy segments would make the sum negative
        proxy_v = variance + np.maximum(mismatch_q / q - mismatch, 0.0)
        proxy_c = n * rho + exact * q * n_q
        use = proxy_v + lam * proxy_c < variance + lam * base * n
        v = np.where(use, proxy_v, variance).sum()
        c = np.where(use, proxy_c, base * n).sum()
        lam = v / c
    return use, q, float(total_v * base * total_n / (v * c))


def region_measures(sample_sets, region, weight=None):
    """Per film region and emitter, from the pilot's per-pixel sums (`shade_proxy`'s, every segment tested both
    ways) of two independent sets of camera samples, one per pixel: the sums' means over the two sets, and the
    variance of exact visibility's Σ w V over a camera sample's segments summed over the region's samples,
    estimated from the two sets' differences pixel by pixel, the mismatch energy and Σ (V - V_P)² w, all three
    weighted per pixel by `weight`. What a camera sample's point adds to that variance counts once per camera
    sample, not once per segment."""
    first, second = sample_sets
    weight = (np.ones(len(region)) if weight is None else weight)[:, None]
    sums = np.zeros((REGIONS * REGIONS,) + first.shape[1:])
    np.add.at(sums, region, 0.5 * (first + second))
    variance = np.zeros((REGIONS * REGIONS, first.shape[1]))
    np.add.at(variance, region, 0.5 * (first[..., SUM_WV] - second[..., SUM_WV]) ** 2 * weight)
    mismatch = np.zeros((REGIONS * REGIONS, first.shape[1]))
    np.add.at(mismatch, region, 0.5 * (first[..., SUM_MISMATCH] + second[..., SUM_MISMATCH]) * weight)
    mismatch_w = np.zeros((REGIONS * REGIONS, first.shape[1]))
    np.add.at(mismatch_w, region, 0.5 * (first[..., SUM_MISMATCH_W] + second[..., SUM_MISMATCH_W]) * weight)
    return sums, variance, mismatch, mismatch_w


def film_regions(camera, pix):
    """The REGIONS x REGIONS tile of the film that each image pixel (row-major indices) lies in."""
    fw, fh = camera.film_size
    x = (camera.crop_x + pix % camera.width + 0.5) / fw
    y = (camera.crop_y + pix // camera.width + 0.5) / fh
    return (np.minimum(x * REGIONS, REGIONS - 1).astype(np.int64)
            + REGIONS * np.minimum(y * REGIONS, REGIONS - 1).astype(np.int64))


def pilot_pixels(camera, spp):
    """The pilot's grid of the image's own pixels (row-major indices), so that a camera sample varies within one
    as much as in the render: up to PILOT_RESOLUTION along the longer side, at most PILOT_SHARE of the render's
    camera samples."""
    w, h = camera.width, camera.height
    side = int(min(PILOT_RESOLUTION, max(16, np.sqrt(w * h * spp * PILOT_SHARE * max(w, h) / min(w, h)))))
    pw, ph = (side, max(1, round(side * h / w))) if w >= h else (max(1, round(side * w / h)), side)
    pw, ph = min(pw, w), min(ph, h)
    xs, ys = ((np.arange(pw) + 0.5) * w / pw).astype(np.int64), ((np.arange(ph) + 0.5) * h / ph).astype(np.int64)
    return (ys[:, None] * w + xs[None, :]).ravel()


def calls_per_set(tags):
    """Kernel runs of the pilot per set of camera samples after the probe's: without shells, the proxy alone
    and both ways; with them, exact visibility too."""
    return sum(3 if tag == "shells" else 2 for tag in tags)


class Pilot:
    """The pilot of `q=auto`, in two stages so that deciding costs at most PILOT_BUDGET of the render.

    `probe` renders the first set of pilot camera samples with exact visibility (which the plan needs anyway),
    and the same for one camera sample, to tell a run's fixed cost from its cost per sample: from those it
    predicts the render's seconds and the rest of the pilot's, before any proxy is built. Only when the whole
    pilot fits the budget does `plan` build on the probe: the second set, the proxy kernel's runs, the plan.
    """

    def __init__(self, integrator, settings):
        self.integrator = integrator
        self.settings = settings
        self.pixels = pilot_pixels(integrator.scene.camera, settings.spp)
        self.seed = (settings.seed ^ PILOT_SALT) & MAX_SEED  # apart from the render's samples, a valid seed still
        self.best = {}  # the fastest time of each kernel run over the sets of camera samples
        self.batches = []
        self.predicted = {}  # seconds: the render, the whole pilot, and its budget

    def _batch(self, pixels, r):
        batch = self.integrator.shading_batch(pixels, 1, self.settings.shadow_rays, (self.seed + r) & MAX_SEED)
        return batch._replace(cases=np.full_like(batch.cases, CASE_UNKNOWN))

    def _timed(self, name, run, batches):
        outs = []
        for batch in batches:
            t0 = time.perf_counter()
            outs.append(run(batch))
            self.best[name] = min(self.best.get(name, np.inf), time.perf_counter() - t0)
        return outs

    def probe(self, tags, before=0.0):
        """Time camera rays and exact visibility on the first set of pilot samples and on one sample (twice: the
        first run may load kernels), for a pilot of the configurations `tags`; True if the pilot's predicted
        seconds, with the `before` seconds that deciding took already (the survey), fit PILOT_BUDGET of the
        render's."""
        t_start = time.perf_counter() - before
        one = {"camera": np.inf, "exact": np.inf}
        for _ in range(2):
            t0 = time.perf_counter()
            single = self._batch(self.pixels[:1], 0)
            t1 = time.perf_counter()
            self.integrator.shade_exact(single)
            one["camera"] = min(one["camera"], t1 - t0)
            one["exact"] = min(one["exact"], time.perf_counter() - t1)
        t0 = time.perf_counter()
        self.batches.append(self._batch(self.pixels, 0))
        self.best["camera"] = time.perf_counter() - t0
        self._timed("exact_plain", self.integrator.shade_exact, self.batches)
        cam = self.integrator.scene.camera
        n_pilot, n_render = len(self.pixels), cam.width * cam.height * self.settings.spp
        per_run = self.best["camera"] + self.best["exact_plain"]
        fixed = one["camera"] + one["exact"]
        per_sample = (per_run - fixed) / max(n_pilot - 1, 1)
        if per_sample <= 0.0:  # timing noise on a tiny pilot: charge every sample the whole run's average
            per_sample, fixed = per_run / n_pilot, 0.0
        spent = time.perf_counter() - t_start
        # the second set's camera rays and exact visibility, then the proxy kernel's runs on both sets, each
        # about as dear as exact visibility's
        rest = per_run + PILOT_SETS * calls_per_set(tags) * self.best["exact_plain"]
        self.predicted = {"render_seconds": fixed + per_sample * n_render, "pilot_seconds": spent + rest}
        self.predicted["budget_seconds"] = PILOT_BUDGET * self.predicted["render_seconds"]
        return self.predicted["pilot_seconds"] <= self.predicted["budget_seconds"]

    def plan(self, kernel, configs, q_default):
        """Measure and plan (a `Plan`) after `probe`. `kernel(batch, shells, correction)` runs the proxy kernel;
        `configs` maps "plain" (no shells) and/or "shells" to `ShellTests`: the configurations to choose from."""
        scene = self.integrator.scene
        cam, e = scene.camera, scene.n_emitters
        n_pix = len(self.pixels)
        for r in range(1, PILOT_SETS):  # camera rays, which every method pays: they dilute the gain
            t0 = time.perf_counter()
            self.batches.append(self._batch(self.pixels, r))
            self.best["camera"] = min(self.best["camera"], time.perf_counter() - t0)
        self._timed("exact_plain", self.integrator.shade_exact, self.batches[1:])
        constant = np.zeros(e)  # q the same for every segment
        measure_all = Correction(np.ones((n_pix, e)), np.zeros((n_pix, e), bool), constant)
        proxy_only = Correction(np.zeros((n_pix, e)), np.zeros((n_pix, e), bool), constant)
        exact_only = Correction(np.ones((n_pix, e)), np.ones((n_pix, e), bool), constant)
        region = film_regions(cam, self.pixels)

        def measure(tag, shells):
            """Time the proxy kernel with no exact test and with every segment tested both ways (and exact
            visibility, with shells) under one configuration of shells; the measures per region."""
            if shells.active:
                self._timed("exact_" + tag, lambda b: kernel(b, shells, exact_only), self.batches)
            self._timed("proxy_" + tag, lambda b: kernel(b, shells, proxy_only), self.batches)
            outs = self._timed("both_" + tag, lambda b: kernel(b, shells, measure_all), self.batches)
            # errors are judged relative to the pixel (relMSE): each pixel weighs 1 / (its luminance² + 0.01)
            lum = 0.5 * sum(out[0] @ LUMINANCE for out in outs)
            return region_measures([out[3] for out in outs], region, 1.0 / (lum ** 2 + 0.01))

        measured = {tag: measure(tag, shells) for tag, shells in configs.items()}
        return choose(measured, self.best, configs, e, q_default)


def choose(measured, best, configs, e, q_default):
    """The `Plan` from the pilot's measures per configuration (`region_measures`) and its best times per run:
    per emitter, exact visibility or the proxy with q per region (`allocate`) for a segment of the emitter's
    mean weight, each segment's q in proportion to its weight (`segment_q`), in the configuration whose plan
    predicts more."""
    unit = best["exact_plain"]  # costs relative to exact visibility's fused kernel without shells
    kappa = best["camera"] / unit
    plans = {}
    for tag, (sums, pair_variance, pair_mismatch, pair_mismatch_w) in measured.items():
        if sums[..., SUM_INV_P].sum() == 0:
            continue
        base = best.get("exact_" + tag, unit) / unit
        # the extra exact tests' cost is a difference of two timings: floored, so noise cannot zero it
        rho = best["proxy_" + tag] / unit
        cost_e = max(best["both_" + tag] - best["proxy_" + tag], 0.01 * unit) / unit
        both, w_sum = sums[..., SUM_BOTH].sum(axis=0), sums[..., SUM_W].sum(axis=0)
        weight = np.where(both > 0, w_sum / np.maximum(both, 1), 0.0)  # per emitter, the mean weight
        emitter_plans, score = [], []
        for k in range(e):
            n, mismatch, variance = sums[:, k, SUM_INV_P], pair_mismatch[:, k], pair_variance[:, k]
            if n.sum() == 0:
                emitter_plans.append(None)
                continue
            # no segment tested both ways (the shells decided them all): one q for every segment
            mismatch_w, n_w = ((pair_mismatch_w[:, k] * weight[k], sums[:, k, SUM_W] / weight[k]) if weight[k] > 0
                               else (mismatch, n))
            shrunk = []
            for x in (mismatch, variance, mismatch_w, n_w):
                shrunk.append((x + SHRINK * x.sum() / n.sum()) * n / (n + SHRINK))
            mismatch, variance, mismatch_w, n_w = shrunk
            use, q, gain = allocate(n, variance, mismatch, rho + kappa, cost_e, base + kappa,
                                    scaled=(mismatch_w, n_w))
            use &= gain >= GAIN_MARGIN
            emitter_plans.append((use, q, gain * (1 + kappa) / (base + kappa)))
            # a plan that uses the proxies must win by the margin, as within a configuration
            score.append((gain / GAIN_MARGIN if use.any() else 1.0) * (1 + kappa) / (base + kappa))
        plans[tag] = (float(np.mean(score)), (rho, cost_e), sums, emitter_plans, weight)
    regions = REGIONS * REGIONS
    plan = Plan(np.zeros((regions, e), bool), np.full((regions, e), q_default), np.full(e, np.nan),
                configs.get("shells") or configs["plain"], False, np.zeros(e), camera_cost=kappa,
                sums=np.zeros((e, N_SUMS)))
    if not plans:
        return plan
    # with shells or without, whichever the pilot finds better; shells must win by SHELL_MARGIN (their walk
    # costs a few percent where it decides nothing, within the pilot's timing noise)
    tag = max(plans, key=lambda t: plans[t][0] / (SHELL_MARGIN if t == "shells" else 1.0))
    _, plan.costs, sums, emitter_plans, plan.weight = plans[tag]
    plan.shells = configs[tag]
    plan.shells_dropped = tag == "plain" and "shells" in configs
    plan.sums = sums.sum(axis=0)
    plan.segments = int(sums[..., SUM_INV_P].sum())
    for k, chosen in enumerate(emitter_plans):
        if chosen is None:
            continue
        use, q, plan.gain[k] = chosen
        plan.exact[:, k] = ~use
        plan.q[:, k] = np.where(use, q, plan.q[:, k])
    return plan
