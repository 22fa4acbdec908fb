"""Proxy visibility: every segment is tested against simplified proxy geometry, and a random fraction q of them
against the scene as well, as the control variate V = V_P + B (V - V_P) / q with B ~ Bernoulli(q) (Billen,
Lagae and Dutré, EGSR 2014). Unbiased for any q > 0; it pays where the proxy test is much cheaper than the
exact one (heavy meshes whose BVH leaves the cache) and the two rarely disagree.

Efficiency-aware q (`q=auto`): with δ the mismatch energy E[(V - V_P)² w²] relative to the variance of
exactly-tested contributions w V (w the segment's unoccluded contribution), ρ the cost per segment of this
estimator's kernel without the exact test (sampling, the proxy test, the film) and e that of the extra exact
test, both relative to exact visibility's fused kernel, the variance × cost is σ² (1 - δ + δ/q)(ρ + q e),
least at q = √(δ ρ / ((1 - δ) e)), where the gain over exact visibility is G = 1 / (√(ρ (1 - δ)) + √(δ e))²
(with e = 1, the 2014 paper's control-variate gain). ρ and e are measured by a pilot in `prepare` - the
camera's view at PILOT_RESOLUTION², one sample per pixel, rendered by the fused exact kernel and by this
estimator's, every segment traced both ways - which also starts δ; δ is then a running estimate over earlier batches, so a
batch's q never depends on its own draws. An emitter whose predicted G falls below GAIN_MARGIN (the pilot
leaves out camera rays and the film, which every method pays, so it over-predicts) gets exact visibility
only: proxies that do not pay are not used, and when that is every emitter the render takes exact
visibility's fused kernel.

A proxy strays from its mesh by about its edge length, so a segment leaving a heavy mesh's own surface would
often hit the proxy at once: the proxy test ignores the first `ProxyGeometry.clearance` of every segment (any
V_P is a valid control variate; this one just agrees with V more often).
"""
import time

import numpy as np

from ..accel import build_bvh, occluded_segments
from ..errors import ProbvisError
from ..proxies import MIN_TRIANGLES, build_proxies
from ..rng import uniforms
from ..settings import MAX_SEED
from .base import Option, Phase, VisibilityEstimator, VisibilityResult
from .proxy_kernel import CORRECTION_DIM, shade_proxy

PILOT_Q = 0.5  # q of a batch before anything is measured (a pilot that found no segment)
PILOT_RESOLUTION = 32  # the pilot's image size: 1024 camera samples
PILOT_SALT = 0x50524F5859  # mixed into its seed, apart from the render's samples
Q_MIN = 0.02  # auto: never test fewer segments exactly than this
MIN_MEASURED = 256  # segments of an emitter tested both ways before its measured δ is trusted
GAIN_MARGIN = 1.25  # proxies are used where the predicted gain exceeds this: the pilot leaves out shared costs


def _parse_q(value):
    if value == "auto":
        return None
    try:
        q = float(value)
    except ValueError:
        return f"must be auto or a probability in (0, 1], got {value!r}"
    return None if 0.0 < q <= 1.0 else f"must be auto or a probability in (0, 1], got {value!r}"


def predicted_gain(rho, delta, exact=1.0):
    """Efficiency of the control variate at its best q relative to exact visibility, with `rho` the cost of a
    segment's proxy test and `exact` that of its extra exact test, both relative to exact visibility's cost per
    segment: 1 / (√(ρ (1 - δ)) + √(δ e))²."""
    return 1.0 / (np.sqrt(rho * (1.0 - delta)) + np.sqrt(delta * exact)) ** 2


def best_q(rho, delta, exact=1.0):
    """The q minimising variance x cost, √(δ ρ / ((1 - δ) e)), within [Q_MIN, 1]."""
    return float(np.clip(np.sqrt(delta * rho / (max(1.0 - delta, 1e-12) * max(exact, 1e-12))), Q_MIN, 1.0))


class ProxyVisibility(VisibilityEstimator):
    name = "proxy"
    summary = "proxy geometry for every segment, the scene for a random fraction q (control variate, unbiased)"
    options = (
        Option("ratio", float, 0.01, "share of a heavy mesh's triangles its proxy keeps, in (0, 1)",
               check=lambda r: None if 0.0 < r < 1.0 else f"must be in (0, 1), got {r:g}"),
        Option("triangles", int, None, "triangles of each proxy (instead of ratio)", minimum=4),
        Option("min_triangles", int, MIN_TRIANGLES, "meshes with fewer triangles are used as they are",
               minimum=4),
        Option("q", str, "auto", "probability of also testing a segment exactly: auto (efficiency-aware, per "
               "emitter) or a number in (0, 1]", check=_parse_q, metavar="auto|Q"),
        Option("cache", bool, True, "cache proxies on disk ($PROBVIS_CACHE_DIR, default ~/.cache/probvis)"),
    )
    phases = (
        Phase("proxies", "prepare", "decimating heavy meshes (or reading them from the cache)"),
        Phase("proxy_bvh", "prepare", "building the proxy geometry's BVH"),
        Phase("pilot", "prepare", "measuring proxy and scene tests on a small view of the scene (q=auto)"),
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
            self.proxies = build_proxies(scene, p.ratio, p.triangles, p.min_triangles, p.cache)
        with self.timed("proxy_bvh"):
            self.proxy_bvh = build_bvh(self.proxies.triangles)
        e = scene.n_emitters
        self.fixed_q = None if p.q == "auto" else float(p.q)
        self.q = np.full(e, self.fixed_q or PILOT_Q)
        self.exact_only = np.zeros(e, bool)
        # running sums over segments tested both ways, per emitter: count, Σ (V - V_P)² w², Σ w V, Σ (w V)²
        self.sums = np.zeros((e, 4))
        self.tests = {"proxy": np.zeros(2, np.int64), "scene": np.zeros(2, np.int64)}
        self.pilot_segments = 0
        self.costs = None  # (ρ, e) from the pilot: costs relative to exact visibility's fused kernel
        if self.proxies.n_decimated == 0:
            self.exact_only[:] = True  # nothing to gain: every segment is tested exactly
        elif self.fixed_q is None:
            with self.timed("pilot"):
                self._pilot(scene, bvh, emitters, settings)
            self._update_q()

    @property
    def fused_any_hit(self):
        """Exact visibility's fused kernel serves a render in which every emitter went exact-only."""
        only = getattr(self, "exact_only", None)
        return only is not None and bool(only.all())

    def _pilot(self, scene, bvh, emitters, settings):
        """Measure costs and δ on a small rendering of the camera's view: exact visibility's fused kernel, this
        estimator's kernel with no exact test (q = 0) and with every segment tested both ways (q = 1)."""
        from ..accel import nearest_hits
        from ..camera import camera_params, camera_rays
        from ..fused_exact import shade_exact
        from ..interaction import scene_arrays, surface_interactions
        from .base import CASE_UNKNOWN

        small = scene.with_resolution(PILOT_RESOLUTION, PILOT_RESOLUTION)
        n_pix, n_shadow = PILOT_RESOLUTION ** 2, settings.shadow_rays
        seed = (settings.seed ^ PILOT_SALT) & MAX_SEED  # apart from the render's samples, a valid seed still
        org, dirs, tmin, tmax, keys = camera_rays(camera_params(small.camera), 1, seed, 0, n_pix)
        prim, _, b1, b2, cam_node, cam_tri = nearest_hits(bvh, org, dirs, tmin, tmax)
        geom, textures = scene_arrays(scene)
        its = surface_interactions(geom, textures, prim, b1, b2, dirs)
        cases = np.full((n_pix, scene.n_emitters), CASE_UNKNOWN, np.int8)
        args = (geom, emitters.arrays)
        pixel = (prim, its.position, its.normal, its.material, its.albedo, cases, keys, its.emitted, cam_node,
                 cam_tri, 1, n_shadow, n_pix)
        zeros, ones, none = np.zeros(scene.n_emitters), np.ones(scene.n_emitters), np.zeros(scene.n_emitters, bool)
        best = {}
        for name, run in (("exact", lambda: shade_exact(*args, bvh.arrays, *pixel)),
                          ("proxy", lambda: self._kernel(geom, emitters.arrays, pixel, zeros, none)),
                          ("both", lambda: self._kernel(geom, emitters.arrays, pixel, ones, none))):
            t0 = time.perf_counter()
            out = run()
            best[name] = time.perf_counter() - t0
        sums = out[4]
        if sums[:, 0].sum() == 0:
            return
        # the extra exact tests' cost is a difference of two timings: floored, so timing noise cannot zero it
        self.costs = (best["proxy"] / best["exact"], max(best["both"] - best["proxy"], 0.01 * best["exact"])
                      / best["exact"])
        self.sums += sums
        self.pilot_segments = int(sums[:, 0].sum())

    def _kernel(self, geom, es, pixel, q, exact_only):
        (prim, pos, nrm, mat, albedo, cases, keys, emitted, cam_node, cam_tri, spp, n_shadow, n_pix) = pixel
        return shade_proxy(geom, es, self.bvh.arrays, self.proxy_bvh.arrays, prim, pos, nrm, mat, albedo, cases, keys,
                           emitted, cam_node, cam_tri, spp, n_shadow, n_pix, q, exact_only, self.proxies.clearance)

    def classify(self, points):
        """No cases; q and exact-only are settled here, before the integrator picks this batch's kernel."""
        self._update_q()
        return None

    def shade(self, geom, emitters, interactions, cases, keys, cam_node, cam_tri, spp, n_shadow, n_pix):
        its = interactions
        with self.timed("render_kernel"):
            img, m2, counts, n_seg, sums, tests = self._kernel(
                geom, emitters, (its.triangle, its.position, its.normal, its.material, its.albedo, cases, keys,
                                 its.emitted, cam_node, cam_tri, spp, n_shadow, n_pix),
                np.where(self.exact_only, 1.0, self.q), self.exact_only)
        self.sums += sums
        self.tests["proxy"] += tests[:2]
        self.tests["scene"] += tests[2:]
        return img, m2, counts, n_seg

    def _accumulate(self, emitter, w, v, v_p):
        """Add segments tested both ways to the per-emitter sums behind δ."""
        np.add.at(self.sums, (emitter, 0), 1.0)
        np.add.at(self.sums, (emitter, 1), ((v - v_p) * w) ** 2)
        np.add.at(self.sums, (emitter, 2), w * v)
        np.add.at(self.sums, (emitter, 3), (w * v) ** 2)

    def _update_q(self):
        """q (and exact-only) per emitter from the pilot's costs and the mismatches measured so far (fixed q, or
        a pilot that found no segment: q stays as it is)."""
        if self.fixed_q is not None or self.costs is None:
            return
        rho, exact = self.costs
        for e in range(len(self.q)):
            n, mismatch, s1, s2 = self.sums[e]
            if self.exact_only[e] or n < MIN_MEASURED:
                continue
            variance = s2 / n - (s1 / n) ** 2
            delta = 1.0 if variance <= 0 else min(mismatch / n / variance, 1.0)
            if predicted_gain(rho, delta, exact) < GAIN_MARGIN:
                self.exact_only[e] = True
            else:
                self.q[e] = best_q(rho, delta, exact)

    def evaluate(self, query):
        self._update_q()
        n = len(query.tmax)
        exact_only = self.exact_only[query.emitter]
        q = np.where(exact_only, 1.0, self.q[query.emitter])
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
        v_p[on_proxy] = 1.0 - occ
        node[on_proxy] += pn
        tri[on_proxy] += pt
        with self.timed("exact_trace"):
            occ, sn, st = occluded_segments(self.bvh, query.origin[on_scene], query.direction[on_scene],
                                            query.tmax[on_scene], query.point[on_scene])
        v = 1.0 - occ
        node[on_scene] += sn
        tri[on_scene] += st
        self.tests["proxy"] += (int(pn.sum()), int(pt.sum()))
        self.tests["scene"] += (int(sn.sum()), int(st.sum()))
        value = np.where(exact_only, 0.0, v_p)
        value[on_scene] += np.where(exact_only[on_scene], v, (v - v_p[on_scene]) / q[on_scene])
        both = on_scene[~exact_only[on_scene]]
        if len(both):
            w = query.weight[both] if query.weight is not None else np.ones(len(both))
            self._accumulate(query.emitter[both], w, v[~exact_only[on_scene]], v_p[both])
        return VisibilityResult(value, node, tri)

    def memory_estimate(self, scene, settings, batch_samples):
        p = self.params
        heavy = [s.n_triangles for s in scene.shapes if s.n_triangles >= p.min_triangles and s.emitter < 0]
        proxy = p.ratio * sum(heavy) if p.triangles is None else p.triangles * len(heavy)
        # triangles (72 bytes) and their BVH (about twice that again)
        return {"proxy geometry and its BVH (ratio, triangles)": int((scene.n_triangles - sum(heavy) + proxy) * 200)}

    def stats(self):
        out = super().stats()
        n, mismatch, s1, s2 = self.sums.T
        with np.errstate(divide="ignore", invalid="ignore"):
            variance = s2 / n - (s1 / n) ** 2
            delta = np.where(variance > 0, mismatch / n / variance, np.nan)
        rho, exact = self.costs if self.costs is not None else (None, None)
        out.update({
            "proxies": self.proxies.shapes, "proxy_triangles": len(self.proxies.triangles),
            "tests": {k: {"node": int(v[0]), "triangle": int(v[1])} for k, v in self.tests.items()},
            "cost_ratio": rho, "exact_cost_ratio": exact,
            "pilot_segments": self.pilot_segments,
            "emitters": [{"q": None if x else float(qq), "exact_only": bool(x), "segments_measured": int(c),
                          "mismatch_energy": None if not np.isfinite(d) else float(d),
                          "predicted_gain": (None if rho is None or not np.isfinite(d) else
                                             float(predicted_gain(rho, min(d, 1.0), exact)))}
                         for qq, x, c, d in zip(self.q, self.exact_only, n, delta)],
        })
        return out
