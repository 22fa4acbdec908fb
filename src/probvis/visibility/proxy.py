"""Proxy visibility: every segment is tested against simplified proxy geometry, and a random fraction q of them
against the scene as well, as the control variate V = V_P + B (V - V_P) / q with B ~ Bernoulli(q) (Billen,
Lagae and Dutré, EGSR 2014). Unbiased for any q > 0; it pays where the proxy test is much cheaper than the
exact one (heavy meshes whose BVH leaves the cache) and the two rarely disagree.

Efficiency-aware q (`q=auto`), per emitter and image region (the 2014 paper's choice among the original
geometry, the proxy and the correction, made per region): with ρ the cost per segment of this estimator's
kernel without the exact test (sampling, the proxy test, the film) and e that of the extra exact test, both
relative to exact visibility's fused kernel, a region r of n_r segments, exact variance V_r and mismatch energy
M_r = Σ (V - V_P)² w² (w the segment's unoccluded contribution) adds variance V_r - M_r + M_r / q_r at cost
n_r (ρ + e q_r), or V_r at cost n_r with exact visibility alone. V_r is the variance of the region's sum of
w V over its camera samples, measured from two independent sets of them: what a camera sample's point and
material add counts once per camera sample, not once per segment, so that many shadow rays per camera sample
(their visibility variance then a small share of the pixel's) leave more to gain. The product of total
variance and total cost is least where every region takes the cheaper of the two at the exchange rate
λ = variance / cost, with q_r = √(M_r / (λ e n_r)) (for one region, q = √(δ ρ / ((1 - δ) e)) and the gain
over exact visibility G = 1 / (√(ρ (1 - δ)) + √(δ e))², δ = M / V: with e = 1 the 2014 paper's control-variate
gain); a few rounds of updating λ settle it. ρ, e, V_r and M_r come from a pilot in `prepare`: a grid of the image's pixels, up to
PILOT_RESOLUTION along its longer side (and at most PILOT_SHARE of the render's samples), one sample per pixel,
rendered by the exact fused kernel and by this estimator's, with the shells if any and without them (the
render takes the configuration whose plan predicts more), every segment traced both ways, for each of two
sets of camera samples;
each region's mismatch and variance are shrunk toward its emitter's by SHRINK segments' worth. The pilot's
pixels are the render's own, not a smaller image's larger ones, so that a camera sample varies within one as
much as in the render. The camera rays, which every method pays, are timed too (κ, relative to the exact
kernel) and added to both paths' costs, so the gain shrinks where shadow rays are few per camera sample. An
emitter whose predicted G falls below GAIN_MARGIN (timings of a small view flatter the proxy's cache-resident
BVH) gets exact visibility everywhere: proxies that do not pay are not used, and when that is every emitter the
render takes exact visibility's fused kernel. The pilot uses its own samples, so q never depends on the
render's draws.

Heavy meshes of many separate small parts (foliage) get a volumetric proxy instead of a decimated one
(`--kind`, see `probvis.proxies` and `probvis.transmittance`): V_P is then the proxy BVH's visibility times the
transmittance exp(-∫σ) of the segment through their extinction grid, a real number in [0, 1].

A proxy strays from its mesh by about its edge length, so a segment leaving a heavy mesh's own surface would
often hit the proxy at once: the proxy test ignores the first `ProxyGeometry.clearance` of every segment (any
V_P is a valid control variate; this one just agrees with V more often).
"""
import time

import numpy as np

from ..accel import build_bvh, occluded_segments
from ..emitters import LUMINANCE
from ..errors import ProbvisError
from ..proxies import KINDS, MIN_TRIANGLES, build_proxies
from ..rng import uniforms
from ..settings import MAX_SEED
from ..shells import ShellTests, shell_memory, shell_tests
from ..transmittance import RESOLUTION as VOLUME_RESOLUTION, transmittances
from .base import Option, Phase, VisibilityEstimator, VisibilityResult
from .proxy_kernel import CORRECTION_DIM, shade_proxy

PILOT_Q = 0.5  # q where the pilot measured nothing (it found no segment)
PILOT_RESOLUTION = 64  # the pilot's pixels along the image's longer side: up to 4,096 camera samples,
PILOT_SHARE = 1 / 300  # and at most this share of the render's (six kernel runs: about 2% of its time)
PILOT_SETS = 2  # independent sets of pilot camera samples: their differences give the variance; each kernel
# runs on both and the faster time is kept (the first call may load or compile)
REGIONS = 8  # q=auto chooses q per emitter in REGIONS x REGIONS tiles of the film
SHRINK = 256  # a region's mismatch energy and variance are shrunk toward its emitter's by this many segments' worth
PILOT_SALT = 0x50524F5859  # mixed into its seed, apart from the render's samples
Q_MIN = 0.02  # auto: never test fewer segments exactly than this
GAIN_MARGIN = 1.25  # proxies are used where the predicted gain exceeds this: a small view flatters them
SHELL_MARGIN = 1.05  # shells are kept where their plan predicts this much more than the plan without them


def _parse_q(value):
    if value == "auto":
        return None
    try:
        q = float(value)
    except ValueError:
        return f"must be auto or a probability in (0, 1], got {value!r}"
    return None if 0.0 < q <= 1.0 else f"must be auto or a probability in (0, 1], got {value!r}"


def allocate(n, variance, mismatch, rho, exact=1.0, base=1.0, rounds=20):
    """Per region (arrays over regions of one emitter: segments, exact visibility's variance of the region's sum
    over its camera samples, mismatch energy) whether to
    use the proxy and its q, minimising total variance x total cost, with costs per segment `base` for exact
    visibility and `rho` + `exact` q for the proxy; and the predicted gain over exact visibility,
    (Σ V) base n / (variance x cost)."""
    n, variance, mismatch = (np.asarray(x, float) for x in (n, variance, mismatch))
    total_v, total_n = variance.sum(), n.sum()
    if total_v <= 0 or total_n <= 0:
        return np.zeros(len(n), bool), np.ones(len(n)), 1.0
    lam = total_v / (base * total_n)
    for _ in range(rounds):
        with np.errstate(divide="ignore", invalid="ignore"):
            q = np.clip(np.sqrt(np.where(n > 0, mismatch / (lam * exact * n), 1.0)), Q_MIN, 1.0)
        proxy_v = variance - mismatch + mismatch / q
        proxy_c = n * (rho + exact * q)
        use = proxy_v + lam * proxy_c < variance + lam * base * n
        v = np.where(use, proxy_v, variance).sum()
        c = np.where(use, proxy_c, base * n).sum()
        lam = v / c
    return use, q, float(total_v * base * total_n / (v * c))


def region_measures(sample_sets, region, weight=None):
    """Per film region and emitter, from the pilot's per-pixel sums (`shade_proxy`'s, every segment tested both
    ways) of two independent sets of camera samples, one per pixel: the sums' means over the two sets, and the
    variance of exact visibility's Σ w V over a camera sample's segments summed over the region's samples,
    estimated from the two sets' differences pixel by pixel, and the mismatch energy (the sums' second column),
    both weighted per pixel by `weight`. What a camera sample's point adds to that variance counts once per
    camera sample, not once per segment."""
    first, second = sample_sets
    weight = (np.ones(len(region)) if weight is None else weight)[:, None]
    sums = np.zeros((REGIONS * REGIONS,) + first.shape[1:])
    np.add.at(sums, region, 0.5 * (first + second))
    variance = np.zeros((REGIONS * REGIONS, first.shape[1]))
    np.add.at(variance, region, 0.5 * (first[..., 2] - second[..., 2]) ** 2 * weight)
    mismatch = np.zeros((REGIONS * REGIONS, first.shape[1]))
    np.add.at(mismatch, region, 0.5 * (first[..., 1] + second[..., 1]) * weight)
    return sums, variance, mismatch


def film_regions(camera, pix):
    """The REGIONS x REGIONS tile of the film that each image pixel (row-major indices) lies in."""
    fw, fh = camera.film_size
    x = (camera.crop_x + pix % camera.width + 0.5) / fw
    y = (camera.crop_y + pix // camera.width + 0.5) / fh
    return (np.minimum(x * REGIONS, REGIONS - 1).astype(np.int64)
            + REGIONS * np.minimum(y * REGIONS, REGIONS - 1).astype(np.int64))


class ProxyVisibility(VisibilityEstimator):
    name = "proxy"
    summary = "proxy geometry for every segment, the scene for a random fraction q (control variate, unbiased)"
    options = (
        Option("ratio", float, 0.01, "share of a heavy mesh's triangles its proxy keeps, in (0, 1)",
               check=lambda r: None if 0.0 < r < 1.0 else f"must be in (0, 1), got {r:g}"),
        Option("triangles", int, None, "triangles of each proxy (instead of ratio)", minimum=4),
        Option("min_triangles", int, MIN_TRIANGLES, "meshes with fewer triangles are used as they are",
               minimum=4),
        Option("kind", str, "auto", "proxy of a heavy mesh: a decimated mesh, an extinction grid (volume), or auto: "
               "volume for meshes of mostly separate small parts (foliage), mesh otherwise", choices=KINDS),
        Option("q", str, "auto", "probability of also testing a segment exactly: auto (efficiency-aware, per "
               "emitter) or a number in (0, 1]", check=_parse_q, metavar="auto|Q"),
        Option("shells", bool, True, "decide segments exactly by conservative shells of the heavy meshes first"),
        Option("cache", bool, True, "cache proxies and shells on disk ($PROBVIS_CACHE_DIR, default ~/.cache/probvis)"),
    )
    phases = (
        Phase("proxies", "prepare", "decimating heavy meshes or prefiltering them into an extinction grid (or "
              "reading the cache)"),
        Phase("proxy_bvh", "prepare", "building the proxy geometry's BVH"),
        Phase("shells", "prepare", "building the shells' voxel grid and the BVH of the rest of the scene (or reading the cache)"),
        Phase("pilot", "prepare", "measuring proxy and scene tests on a grid of the image's pixels (q=auto)"),
        Phase("render_kernel", "batch", "sampling, proxy and scene tests and the film, fused"),
        Phase("proxy_trace", "batch", "testing segments against the proxies (staged interface)"),
        Phase("exact_trace", "batch", "testing the chosen segments against the scene (staged interface)"),
    )
    fused_shade = True  # renders through `proxy_kernel.shade_proxy`; `evaluate` serves the staged interface

    def prepare(self, scene, bvh, emitters, settings):
        super().prepare(scene, bvh, emitters, settings)
        p = self.params
        for shape in scene.shapes:
            if p.triangles is not None and p.min_triangles <= shape.n_triangles <= p.triangles:
                raise ProbvisError(f"triangles {p.triangles} is not below the {shape.n_triangles} of mesh "
                                   f"'{shape.name}' (or raise min_triangles above it)")
        with self.timed("proxies"):
            self.proxies = build_proxies(scene, p.ratio, p.triangles, p.min_triangles, p.cache, p.kind)
        has_proxy = self.proxies.n_decimated + self.proxies.n_volumes > 0
        with self.timed("proxy_bvh"):  # no proxy: nothing to test but the scene, whose BVH stands in
            self.proxy_bvh = build_bvh(self.proxies.triangles) if has_proxy else bvh
        with self.timed("shells"):
            self.shells = shell_tests(scene, bvh, p.min_triangles, p.cache) if p.shells else ShellTests.none(bvh)
        e, r = scene.n_emitters, REGIONS * REGIONS
        self.fixed_q = None if p.q == "auto" else float(p.q)
        self.q = np.full((r, e), self.fixed_q or PILOT_Q)  # per region and emitter
        self.exact = np.zeros((r, e), bool)  # regions and emitters that take exact visibility alone
        self.gain = np.full(e, np.nan)  # predicted, per emitter
        # sums per emitter (see `shade_proxy`): segments tested both ways, Σ (V - V_P)² w² / q, Σ w V / p,
        # Σ (w V)² / p, Σ 1 / p over those and the segments the shells decide (p = 1)
        self.sums = np.zeros((e, 5))
        self.tests = np.zeros(6, np.int64)  # node and triangle tests: proxy, scene; shell and proxy voxels
        self.pilot_segments = 0
        self.shells_dropped = False  # the pilot found exact visibility faster without them
        self.costs = None  # (ρ, e) from the pilot: costs relative to exact visibility's fused kernel (no shells)
        self.camera_cost = None  # κ: the camera rays' cost, relative to the same
        if not has_proxy:
            self.exact[:] = True  # nothing to gain: every segment is tested exactly
        elif self.fixed_q is None:
            with self.timed("pilot"):
                self._pilot(scene, bvh, emitters, settings)

    @property
    def fused_any_hit(self):
        """Exact visibility's fused kernel serves a render in which every region of every emitter went exact
        (and no shells decide segments first)."""
        exact = getattr(self, "exact", None)
        return exact is not None and bool(exact.all()) and not self.shells.active

    def _pilot(self, scene, bvh, emitters, settings):
        """Measure costs, variance and mismatch per region on a grid of the image's pixels: exact visibility's
        fused kernel, and this estimator's with no exact test (q = 0) and with every segment tested both ways
        (q = 1), without the shells and, if there are any, with them (and exact visibility with them); then plan
        exact or q per region and emitter for both configurations and keep the one with the larger predicted
        gain over exact visibility."""
        from ..accel import nearest_hits
        from ..camera import camera_params, camera_rays
        from ..fused_exact import shade_exact
        from ..interaction import scene_arrays, surface_interactions
        from .base import CASE_UNKNOWN

        cam = scene.camera
        w, h = cam.width, cam.height
        side = int(min(PILOT_RESOLUTION, max(16, np.sqrt(w * h * settings.spp * PILOT_SHARE * max(w, h) / min(w, h)))))
        pw, ph = (side, max(1, round(side * h / w))) if w >= h else (max(1, round(side * w / h)), side)
        pw, ph = min(pw, w), min(ph, h)
        # a grid of the image's own pixels, so that a camera sample varies as much as in the render
        xs, ys = ((np.arange(pw) + 0.5) * w / pw).astype(np.int64), ((np.arange(ph) + 0.5) * h / ph).astype(np.int64)
        image_pixels = (ys[:, None] * w + xs[None, :]).ravel()
        n_pix, n_shadow, e = pw * ph, settings.shadow_rays, scene.n_emitters
        seed = (settings.seed ^ PILOT_SALT) & MAX_SEED  # apart from the render's samples, a valid seed still
        geom, textures = scene_arrays(scene)
        params = camera_params(cam)
        best, pixels = {}, []
        for r in range(PILOT_SETS):  # camera rays, which every method pays: they dilute the gain
            t0 = time.perf_counter()
            org, dirs, tmin, tmax, keys = camera_rays(params, 1, (seed + r) & MAX_SEED, image_pixels)
            prim, _, b1, b2, cam_node, cam_tri = nearest_hits(bvh, org, dirs, tmin, tmax)
            its = surface_interactions(geom, textures, prim, b1, b2, dirs)
            best["camera"] = min(best.get("camera", np.inf), time.perf_counter() - t0)
            cases = np.full((n_pix, e), CASE_UNKNOWN, np.int8)
            pixels.append((prim, its.position, its.normal, its.material, its.albedo, cases, keys, its.emitted,
                           cam_node, cam_tri, 1, n_shadow, n_pix))
        zeros, ones, none = np.zeros((n_pix, e)), np.ones((n_pix, e)), np.zeros((n_pix, e), bool)

        def timed(name, run):  # on both sets of camera samples, the faster time kept; the outputs
            outs = []
            for px in pixels:
                t0 = time.perf_counter()
                outs.append(run(px))
                best[name] = min(best.get(name, np.inf), time.perf_counter() - t0)
            return outs

        region = film_regions(cam, image_pixels)

        def measure(tag, shells):
            """Time this estimator's kernel with no exact test and with every segment tested both ways (and
            exact visibility, with shells) under one configuration of shells; the measures per region."""
            self.shells = shells
            if shells.active:
                timed("exact_" + tag, lambda px: self._kernel(geom, emitters.arrays, px, ones, ~none))
            timed("proxy_" + tag, lambda px: self._kernel(geom, emitters.arrays, px, zeros, none))
            outs = timed("both_" + tag, lambda px: self._kernel(geom, emitters.arrays, px, ones, none))
            # errors are judged relative to the pixel (relMSE): each pixel weighs 1 / (its luminance² + 0.01)
            lum = 0.5 * sum(out[0] @ LUMINANCE for out in outs)
            return region_measures([out[4] for out in outs], region, 1.0 / (lum ** 2 + 0.01))

        timed("exact_plain", lambda px: shade_exact(geom, emitters.arrays, bvh.arrays, *px))
        configs = {"plain": ShellTests.none(bvh)}
        if self.shells.active:
            configs["shells"] = self.shells
        measured = {tag: measure(tag, shells) for tag, shells in configs.items()}
        unit = best["exact_plain"]  # costs relative to exact visibility's fused kernel without shells
        self.camera_cost = kappa = best["camera"] / unit
        plans = {}
        for tag, (sums, pair_variance, pair_mismatch) in measured.items():
            if sums[..., 4].sum() == 0:
                continue
            base = best.get("exact_" + tag, unit) / unit
            # the extra exact tests' cost is a difference of two timings: floored, so noise cannot zero it
            rho = best["proxy_" + tag] / unit
            cost_e = max(best["both_" + tag] - best["proxy_" + tag], 0.01 * unit) / unit
            emitter_plans, score = [], []
            for k in range(e):
                n, mismatch, variance = sums[:, k, 4], pair_mismatch[:, k], pair_variance[:, k]
                if n.sum() == 0:
                    emitter_plans.append(None)
                    continue
                mu, nu = mismatch.sum() / n.sum(), variance.sum() / n.sum()
                mismatch = (mismatch + SHRINK * mu) * n / (n + SHRINK)
                variance = (variance + SHRINK * nu) * n / (n + SHRINK)
                use, q, gain = allocate(n, variance, mismatch, rho + kappa, cost_e, base + kappa)
                use &= gain >= GAIN_MARGIN
                emitter_plans.append((use, q, gain * (1 + kappa) / (base + kappa)))
                # a plan that uses the proxies must win by the margin, as within a configuration
                score.append((gain / GAIN_MARGIN if use.any() else 1.0) * (1 + kappa) / (base + kappa))
            plans[tag] = (float(np.mean(score)), (rho, cost_e), sums, emitter_plans)
        if not plans:
            self.shells = configs.get("shells", configs["plain"])
            return
        # with shells or without, whichever the pilot finds better; shells must win by SHELL_MARGIN (their walk
        # costs a few percent where it decides nothing, within the pilot's timing noise)
        tag = max(plans, key=lambda t: plans[t][0] / (SHELL_MARGIN if t == "shells" else 1.0))
        _, self.costs, sums, emitter_plans = plans[tag]
        self.shells = configs[tag]
        self.shells_dropped = tag == "plain" and "shells" in configs
        self.sums += sums.sum(axis=0)
        self.pilot_segments = int(sums[..., 4].sum())
        for k, plan in enumerate(emitter_plans):
            if plan is None:
                continue
            use, q, self.gain[k] = plan
            self.exact[:, k] = ~use
            self.q[:, k] = np.where(use, q, self.q[:, k])

    def _kernel(self, geom, es, pixel, q, exact):
        (prim, pos, nrm, mat, albedo, cases, keys, emitted, cam_node, cam_tri, spp, n_shadow, n_pix) = pixel
        return shade_proxy(geom, es, self.bvh.arrays, self.proxy_bvh.arrays, prim, pos, nrm, mat, albedo, cases, keys,
                           emitted, cam_node, cam_tri, spp, n_shadow, n_pix, q, exact, self.proxies.clearance,
                           *self.proxies.volume.kernel_args, *self.shells.kernel_args)

    def shade(self, geom, emitters, interactions, cases, keys, cam_node, cam_tri, spp, n_shadow, n_pix,
              first_pixel):
        its = interactions
        region = film_regions(self.scene.camera, np.arange(first_pixel, first_pixel + n_pix))
        exact = self.exact[region]
        with self.timed("render_kernel"):
            img, m2, counts, n_seg, sums, tests = self._kernel(
                geom, emitters, (its.triangle, its.position, its.normal, its.material, its.albedo, cases, keys,
                                 its.emitted, cam_node, cam_tri, spp, n_shadow, n_pix),
                np.where(exact, 1.0, self.q[region]), exact)
        self.sums += sums.sum(axis=0)
        self.tests += tests
        return img, m2, counts, n_seg

    def _accumulate(self, emitter, w, v, v_p, q):
        """Add segments tested both ways (with probability q) to the per-emitter sums behind δ."""
        for col, x in enumerate((np.ones_like(w), ((v - v_p) * w) ** 2 / q, w * v / q, (w * v) ** 2 / q, 1.0 / q)):
            np.add.at(self.sums, (emitter, col), x)

    def evaluate(self, query):
        """The staged interface (segments without their pixels): per emitter, exact visibility if every region
        takes it, else the proxy with the mean q of the regions that use it."""
        n = len(query.tmax)
        exact_e = self.exact.all(axis=0)
        q_e = np.where(exact_e, 1.0, np.where(self.exact, 0.0, self.q).sum(0) / np.maximum((~self.exact).sum(0), 1))
        exact_only = exact_e[query.emitter]
        q = np.where(exact_only, 1.0, q_e[query.emitter])
        on_proxy = np.flatnonzero(~exact_only)
        traced = exact_only | (uniforms(query.key, CORRECTION_DIM) < q)
        on_scene = np.flatnonzero(traced)
        v_p = np.ones(n)
        node, tri = np.zeros(n, np.int64), np.zeros(n, np.int64)
        with self.timed("proxy_trace"):
            d = query.direction[on_proxy]
            tmin = self.proxies.clearance / np.sqrt(np.einsum("ij,ij->i", d, d))
            occ, pn, pt = occluded_segments(self.proxy_bvh, query.origin[on_proxy], d, query.tmax[on_proxy],
                                            query.point[on_proxy], tmin)
            t_p, steps = transmittances(*self.proxies.volume.kernel_args, query.origin[on_proxy], d, query.tmax[on_proxy])
        v_p[on_proxy] = (1.0 - occ) * t_p
        node[on_proxy] += pn
        tri[on_proxy] += pt
        with self.timed("exact_trace"):
            occ, sn, st = occluded_segments(self.bvh, query.origin[on_scene], query.direction[on_scene],
                                            query.tmax[on_scene], query.point[on_scene])
        v = 1.0 - occ
        node[on_scene] += sn
        tri[on_scene] += st
        self.tests[:4] += (int(pn.sum()), int(pt.sum()), int(sn.sum()), int(st.sum()))
        self.tests[5] += int(steps.sum())
        value = np.where(exact_only, 0.0, v_p)
        value[on_scene] += np.where(exact_only[on_scene], v, (v - v_p[on_scene]) / q[on_scene])
        both = on_scene[~exact_only[on_scene]]
        if len(both):
            w = query.weight[both] if query.weight is not None else np.ones(len(both))
            self._accumulate(query.emitter[both], w, v[~exact_only[on_scene]], v_p[both], q[both])
        return VisibilityResult(value, node, tri)

    def memory_estimate(self, scene, settings, batch_samples):
        p = self.params
        heavy = [s.n_triangles for s in scene.shapes if s.n_triangles >= p.min_triangles and s.emitter < 0]
        proxy = p.ratio * sum(heavy) if p.triangles is None else p.triangles * len(heavy)
        # triangles (72 bytes) and their BVH (about twice that again); per pixel of a batch q, exact and the sums
        out = {"proxy geometry and its BVH (ratio, triangles)": int((scene.n_triangles - sum(heavy) + proxy) * 200),
               "volumetric proxies' extinction grid": 8 * VOLUME_RESOLUTION ** 3 if heavy and p.kind != "mesh" else 0,
               "per-pixel q and sums (batch size)": batch_samples // max(1, settings.spp) * scene.n_emitters * 49}
        if p.shells:
            out.update(shell_memory(scene, p.min_triangles))
        return out

    def memory_bytes(self):
        own = self.proxy_bvh.nbytes if self.proxy_bvh is not self.bvh else 0
        return {"proxies": self.proxies.triangles.nbytes + own + self.proxies.volume.nbytes,
                "shells": self.shells.nbytes}

    def stats(self):
        out = super().stats()
        n, mismatch, s1, s2, total = self.sums.T
        with np.errstate(divide="ignore", invalid="ignore"):
            variance = s2 / total - (s1 / total) ** 2
            delta = np.where(variance > 0, mismatch / total / variance, np.nan)
        rho, exact = self.costs if self.costs is not None else (None, None)
        used = ~self.exact
        out.update({
            "proxies": self.proxies.shapes, "proxy_triangles": len(self.proxies.triangles),
            "volume_grid": list(self.proxies.volume.sigma.shape) if self.proxies.n_volumes else None,
            "cost_ratio": rho, "exact_cost_ratio": exact, "camera_cost_ratio": self.camera_cost,
            "pilot_segments": self.pilot_segments,
            "emitters": [{"q": float(self.q[used[:, k], k].mean()) if used[:, k].any() else None,
                          "exact_only": not used[:, k].any(), "regions_with_proxy": int(used[:, k].sum()),
                          "segments_measured": int(n[k]),
                          "mismatch_energy": None if not np.isfinite(delta[k]) else float(delta[k]),
                          "predicted_gain": None if not np.isfinite(self.gain[k]) else float(self.gain[k])}
                         for k in range(len(n))],
        })
        out.update(self.shells.stats(self.tests))
        out["tests"]["proxy"]["voxel"] = int(self.tests[5])
        out["shells_dropped"] = self.shells_dropped
        return out
