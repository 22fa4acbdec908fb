"""Proxy visibility: every segment is tested against simplified proxy geometry, and a random fraction q of them
against the scene as well, as the control variate V = V_P + B (V - V_P) / q with B ~ Bernoulli(q) (Billen,
Lagae and Dutré, EGSR 2014). Unbiased for any q > 0; it pays where the proxy test is much cheaper than the
exact one (heavy meshes whose BVH leaves the cache) and the two rarely disagree.

With `q=auto` a pilot chooses, per emitter and film region, exact visibility alone or the proxy with its own q
(`proxy_plan`); where proxies do not pay for any emitter the render takes exact visibility's fused kernel.
Heavy meshes of many separate small parts (foliage) get a volumetric proxy instead of a decimated one
(`--kind`, see `probvis.proxies` and `probvis.transmittance`): V_P is then the proxy BVH's visibility times the
transmittance exp(-∫σ) of the segment through their extinction grid, a real number in [0, 1].

A proxy strays from its mesh by about its edge length, so a segment leaving a heavy mesh's own surface would
often hit the proxy at once: the proxy test ignores the first `ProxyGeometry.clearance` of every segment (any
V_P is a valid control variate; this one just agrees with V more often).
"""
import warnings

import numba
import numpy as np

from ..accel import build_bvh, occluded_segments
from ..errors import ProbvisError
from ..proxies import KINDS, MIN_TRIANGLES, build_proxies
from ..rng import uniforms
from ..shading import ShadedBatch
from ..shells import ShellTests, shell_memory, shell_tests
from ..transmittance import RESOLUTION as VOLUME_RESOLUTION, transmittances
from .base import Option, Phase, RenderPath, Switch, VisibilityEstimator, VisibilityResult
from .exact import WARM_UP_MIN_TRIANGLES, judge_solid, meshes_for_shells, survey_heavy_meshes
from .occlusion_map.verification import probability_problem
from .proxy_kernel import (CORRECTION_DIM, N_SUMS, N_TESTS, PROXY_NODE, PROXY_TRI, SCENE_NODE, SCENE_TRI, SUM_BOTH,
                           SUM_INV_P, SUM_MISMATCH, SUM_MISMATCH_W, SUM_W, SUM_WV, SUM_WV2, VOLUME_VOXEL,
                           WEIGHT_FLOOR, Correction, geometry_tests, shade_proxy)
from .proxy_plan import REGIONS, Decision, Pilot, decision_key, film_regions

PILOT_Q = 0.5  # q where the pilot measured nothing (it found no segment)
SHAPING = ("ratio", "triangles", "kind", "q", "shells")  # what changes nothing without a heavy mesh


def _parse_q(value):
    return probability_problem(value, ("auto",))


class ProxyVisibility(VisibilityEstimator):
    name = "proxy"
    summary = "proxy geometry for every segment, the scene for a random fraction q (control variate, unbiased)"
    options = (
        Option("ratio", float, 0.01, "share of a heavy mesh's triangles its proxy keeps, in (0, 1)",
               check=lambda r: None if 0.0 < r < 1.0 else f"must be in (0, 1), got {r:g}"),
        Option("triangles", int, None, "triangles of each proxy (instead of ratio)", minimum=4),
        Option("min_triangles", int, MIN_TRIANGLES, "meshes with fewer triangles are used as they are",
               minimum=4, warm_up=WARM_UP_MIN_TRIANGLES),
        Option("kind", str, "auto", "proxy of a heavy mesh: a decimated mesh, an extinction grid (volume), or auto: "
               "volume for meshes of mostly separate small parts (foliage), mesh otherwise", choices=KINDS),
        Option("q", str, "auto", "probability of also testing a segment exactly: auto (efficiency-aware, per "
               "emitter) or a number from 0.001 to 1", check=_parse_q, metavar="auto|Q"),
        Option("shells", Switch, "auto", "decide segments exactly by conservative shells of the heavy meshes first; "
               "auto: of the closed ones that the segments often cross, kept where the pilot predicts they pay"),
        Option("cache", bool, True, "cache proxies, shells and q auto's decision on disk ($PROBVIS_CACHE_DIR, default "
               "~/.cache/probvis)", warm_up=False),
    )
    phases = (
        Phase("survey", "prepare", "a pilot of shadow segments: which heavy meshes they cross"),
        Phase("proxies", "prepare", "decimating heavy meshes or prefiltering them into an extinction grid (or "
              "reading the cache)"),
        Phase("proxy_bvh", "prepare", "building the proxy geometry's BVH"),
        Phase("shells", "prepare", "building the shells' voxel grid and the BVH of the rest of the scene (or reading the cache)"),
        Phase("pilot", "prepare", "measuring proxy and scene tests on a grid of the image's pixels (q=auto)"),
        Phase("render_kernel", "batch", "sampling, proxy and scene tests and the film, fused"),
        Phase("proxy_trace", "batch", "testing segments against the proxies (staged interface)"),
        Phase("exact_trace", "batch", "testing the chosen segments against the scene (staged interface)"),
    )

    def __init__(self, **options):
        self.refuse_both(options, "ratio", "triangles")
        super().__init__(**options)
        self.shaping = [o.name for o in self.options if o.name in SHAPING and self.given(options, o.name)]
        self.threshold_given = self.given(options, "min_triangles")

    @classmethod
    def warm_ups(cls, options, largest=None):
        """With no mesh heavy (exact visibility's fused kernel); if the scene has a mesh of min_triangles, also
        with the warm-up scene's meshes heavy (a proxy size below theirs) and, with q auto, with a fixed q: the
        proxies the pilot may choose on the real scene (on the warm-up's it never runs, over its budget)."""
        run = super().warm_ups(options, largest)[0]
        if cls.given(options, "triangles"):
            run["triangles"] = 4
        plain = [{**run, "min_triangles": MIN_TRIANGLES}]
        if largest is not None and largest < cls.parse_options(options)["min_triangles"]:
            return plain
        return plain + [run] + ([] if cls.given(options, "q") else [{**run, "q": str(PILOT_Q)}])

    def _check_meshes(self, scene):
        """Refuse a proxy size not below a heavy mesh's (before the memory estimate, which would take it)."""
        p = self.params
        for shape in scene.shapes:
            if p.triangles is not None and p.min_triangles <= shape.n_triangles <= p.triangles:
                raise ProbvisError(f"triangles {p.triangles} is not below the {shape.n_triangles} of mesh "
                                   f"'{shape.name}' (or raise min_triangles above it)")

    def prepare(self, scene, bvh, emitters, settings, integrator):
        super().prepare(scene, bvh, emitters, settings, integrator)
        p = self.params
        self._check_meshes(scene)
        if (self.shaping or self.threshold_given) and not any(s.n_triangles >= p.min_triangles and s.emitter < 0
                                                              for s in scene.shapes):
            unused = (f" and {', '.join(self.shaping)} change{'s' * (len(self.shaping) == 1)} nothing"
                      if self.shaping else "")
            warnings.warn(f"visibility 'proxy': no mesh of '{scene.name}' has min_triangles ({p.min_triangles}) "
                          f"triangles or more, so every segment is tested exactly{unused}: lower min_triangles to "
                          "give a mesh a proxy", stacklevel=2)
        e, r = scene.n_emitters, REGIONS * REGIONS
        self.fixed_q = None if p.q == "auto" else float(p.q)
        self.q = np.full((r, e), self.fixed_q or PILOT_Q)  # per region and emitter
        self.exact = np.zeros((r, e), bool)  # regions and emitters that take exact visibility alone
        self.gain = np.full(e, np.nan)  # predicted, per emitter
        self.weight = np.zeros(e)  # per emitter, the weight at which a segment takes q (0: q for every segment)
        self.sums = np.zeros((e, N_SUMS))  # per emitter, the kernel's sums behind δ (`proxy_kernel`)
        self.tests = np.zeros(N_TESTS, np.int64)  # tests by geometry (`proxy_kernel`)
        self.pilot_segments = 0
        self.shells_dropped = False  # the pilot found exact visibility faster without them
        self.costs = None  # (ρ, e) from the pilot: costs relative to exact visibility's fused kernel (no shells)
        self.camera_cost = None  # κ: the camera rays' cost, relative to the same
        self.pilot, self.decision = None, None
        with self.timed("survey"):  # the cheapest evidence first: which heavy meshes the segments cross
            survey = survey_heavy_meshes(scene, integrator, settings, p.min_triangles, p.cache, closedness=False)
        # with q auto and no heavy mesh crossed nor shelled, the decision is exact visibility: no key to hash (all
        # of the scene's triangles, longer than the survey) and no cache to read
        undecided = p.q == "auto" and (any(m.crossed for m in survey) or (p.shells == "on" and survey))
        options = {k: getattr(p, k) for k in ("ratio", "triangles", "min_triangles", "kind", "shells")}
        key = decision_key(integrator, settings, options) if undecided and p.cache else None
        cached = Decision.load(key, e) if key is not None else None
        shapes = {s.first_triangle: s for s in scene.shapes}
        if cached is not None and not set(cached.proxy_meshes + cached.shell_meshes) <= shapes.keys():
            cached = None  # a foreign record
        if cached is None:
            with self.timed("survey"):
                survey = judge_solid(scene, survey, p.cache)
            self.decision = self._decide(scene, bvh, settings, survey)
        else:
            self.decision = cached
        self.decision.cached = cached is not None
        if cached is not None:  # the same scene, view and settings decided before: build only what it chose
            self._build(scene, bvh, set(cached.proxy_meshes), [shapes[f] for f in cached.shell_meshes])
            if cached.plan is not None:
                cached.plan.shells = self.shells
            self._apply(cached.plan)
        elif key is not None:
            self.decision.store(key)

    def _decide(self, scene, bvh, settings, survey):
        """From the heavy meshes' `survey`, probe the pilot's cost, build what may be used and plan (a
        `Decision`)."""
        p = self.params
        shell_meshes = meshes_for_shells(p.shells, survey)
        # with q auto, no proxy for a mesh that few segments come near, nor for any where the pilot would cost
        # more than PILOT_BUDGET of the render: exact visibility then renders, as `exact` would
        only = {m.shape.first_triangle for m in survey if m.crossed or p.q != "auto"}
        tags = (["plain"] if p.shells != "on" or not shell_meshes else []) + (["shells"] if shell_meshes else [])
        self.pilot = Pilot(self.integrator, settings) if p.q == "auto" and only else None
        fits = False
        if self.pilot is not None:
            with self.timed("pilot"):
                fits = self.pilot.probe(tags, self.seconds["survey"])
            only = only if fits else set()
        has_proxy = self._build(scene, bvh, only, shell_meshes)
        plan = None
        if has_proxy and self.fixed_q is None:
            configs = {"plain": ShellTests.none(bvh)} if p.shells != "on" or not self.shells.active else {}
            if self.shells.active:  # with shells (forced on: the only configuration)
                configs["shells"] = self.shells
            with self.timed("pilot"):
                plan = self.pilot.plan(self._kernel, configs, PILOT_Q)
        if not has_proxy or plan is not None:  # a fixed q with proxies keeps it everywhere
            self._apply(plan)
        kept = [] if plan is not None and plan.shells_dropped else shell_meshes
        used = has_proxy and not (plan is not None and plan.exact.all())  # exact everywhere needs no proxy
        return Decision(tuple(sorted(only)) if used else (), tuple(s.first_triangle for s in kept), plan,
                        self.pilot.predicted if self.pilot is not None else None, fits)

    def _build(self, scene, bvh, only, shell_meshes):
        """The proxies of the meshes `only` (first triangles), their BVH and the shells of `shell_meshes`; True if
        there is any proxy."""
        p = self.params
        with self.timed("proxies"):
            self.proxies = build_proxies(scene, p.ratio, p.triangles, p.min_triangles, p.cache, p.kind, only)
        has_proxy = self.proxies.n_decimated + self.proxies.n_volumes > 0
        with self.timed("proxy_bvh"):  # no proxy: nothing to test but the scene, whose BVH stands in
            self.proxy_bvh = build_bvh(self.proxies.triangles) if has_proxy else bvh
        with self.timed("shells"):
            self.shells = shell_tests(scene, bvh, shell_meshes, p.cache)
        return has_proxy

    def _apply(self, plan):
        """Take a `Plan`'s choices; None: exact visibility everywhere (no proxy to test)."""
        if plan is None:
            self.exact[:] = True  # nothing to gain: every segment is tested exactly
            return
        self.exact, self.q, self.gain, self.shells = plan.exact, plan.q, plan.gain, plan.shells
        self.weight = plan.weight
        self.shells_dropped, self.costs, self.camera_cost = plan.shells_dropped, plan.costs, plan.camera_cost
        self.sums += plan.sums
        self.pilot_segments = plan.segments

    def render_path(self):
        """Exact visibility's fused kernel where every region of every emitter went exact (and no shells decide
        segments first); else this estimator's kernel."""
        if self.exact.all() and not self.shells.active:
            return RenderPath.FUSED_EXACT
        return RenderPath.OWN_KERNEL

    def _kernel(self, batch, shells, correction):
        return shade_proxy(self.integrator.scene_arrays, self.emitters.arrays, self.bvh.arrays, batch,
                           self.proxy_bvh.arrays, self.proxies.volume.arrays, self.proxies.clearance, shells.arrays,
                           shells.rest.arrays, correction, numba.get_num_threads())

    def shade(self, batch):
        region = film_regions(self.scene.camera, batch.pixel)
        exact = self.exact[region]
        with self.timed("render_kernel"):
            radiance, counts, n_seg, sums, tests = self._kernel(
                batch, self.shells, Correction(np.where(exact, 1.0, self.q[region]), exact, self.weight))
        self.sums += sums.sum(axis=0)
        self.tests += tests
        return ShadedBatch(radiance, counts, n_seg)

    def _accumulate(self, emitter, w, v, v_p, q):
        """Add segments tested both ways (with probability q) to the per-emitter sums behind δ."""
        for col, x in ((SUM_BOTH, np.ones_like(w)), (SUM_MISMATCH, ((v - v_p) * w) ** 2 / q), (SUM_WV, w * v / q),
                       (SUM_WV2, (w * v) ** 2 / q), (SUM_INV_P, 1.0 / q), (SUM_W, w / q),
                       (SUM_MISMATCH_W, (v - v_p) ** 2 * w / q)):
            np.add.at(self.sums, (emitter, col), x)

    def evaluate(self, query):
        """The staged interface (segments without their pixels): per emitter, exact visibility if every region
        takes it, else the proxy with the mean q of the regions that use it, scaled by the segment's weight as
        `proxy_kernel.segment_q` scales it."""
        n = len(query.tmax)
        exact_e = self.exact.all(axis=0)
        q_e = np.where(exact_e, 1.0, np.where(self.exact, 0.0, self.q).sum(0) / np.maximum((~self.exact).sum(0), 1))
        exact_only = exact_e[query.emitter]
        q = np.where(exact_only, 1.0, q_e[query.emitter])
        ref = self.weight[query.emitter]
        if query.weight is not None and (ref > 0).any():
            with np.errstate(divide="ignore", invalid="ignore"):
                scaled = np.minimum(1.0, q * np.maximum(query.weight / ref, WEIGHT_FLOOR))
            q = np.where(exact_only | (ref <= 0), q, scaled)
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
            t_p, steps = transmittances(self.proxies.volume.arrays, query.origin[on_proxy], d, query.tmax[on_proxy])
        v_p[on_proxy] = (1.0 - occ) * t_p
        node[on_proxy] += pn
        tri[on_proxy] += pt
        with self.timed("exact_trace"):
            occ, sn, st = occluded_segments(self.bvh, query.origin[on_scene], query.direction[on_scene],
                                            query.tmax[on_scene], query.point[on_scene])
        v = 1.0 - occ
        node[on_scene] += sn
        tri[on_scene] += st
        for slot, counted in ((PROXY_NODE, pn), (PROXY_TRI, pt), (SCENE_NODE, sn), (SCENE_TRI, st),
                              (VOLUME_VOXEL, steps)):
            self.tests[slot] += int(counted.sum())
        value = np.where(exact_only, 0.0, v_p)
        value[on_scene] += np.where(exact_only[on_scene], v, (v - v_p[on_scene]) / q[on_scene])
        both = on_scene[~exact_only[on_scene]]
        if len(both):
            w = query.weight[both] if query.weight is not None else np.ones(len(both))
            self._accumulate(query.emitter[both], w, v[~exact_only[on_scene]], v_p[both], q[both])
        return VisibilityResult(value, node, tri)

    def memory_estimate(self, scene, settings, batch_samples):
        self._check_meshes(scene)
        p = self.params
        heavy = [s.n_triangles for s in scene.shapes if s.n_triangles >= p.min_triangles and s.emitter < 0]
        proxy = p.ratio * sum(heavy) if p.triangles is None else p.triangles * len(heavy)
        # triangles (72 bytes) and their BVH (about twice that again); per pixel of a batch q, exact and the sums
        out = {"proxy geometry and its BVH (ratio, triangles)": int((scene.n_triangles - sum(heavy) + proxy) * 200),
               "volumetric proxies' extinction grid": 8 * VOLUME_RESOLUTION ** 3 if heavy and p.kind != "mesh" else 0,
               "per-pixel q and sums (batch size)": batch_samples // max(1, settings.spp) * scene.n_emitters
               * (9 + 8 * N_SUMS)}
        if p.shells != "off":
            out.update(shell_memory(scene, p.min_triangles))
        return out

    def memory_bytes(self):
        """Bytes of what this estimator built: no proxy, nothing (its geometry is then the scene's own arrays)."""
        if self.proxy_bvh is self.bvh:
            return {"proxies": 0, "shells": self.shells.nbytes}
        return {"proxies": self.proxies.triangles.nbytes + self.proxy_bvh.nbytes + self.proxies.volume.nbytes,
                "shells": self.shells.nbytes}

    def stats(self):
        out = super().stats()
        n, mismatch, s1, s2, total = (self.sums[:, slot] for slot in (SUM_BOTH, SUM_MISMATCH, SUM_WV, SUM_WV2,
                                                                     SUM_INV_P))
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
                          "predicted_gain": None if not np.isfinite(self.gain[k]) else float(self.gain[k]),
                          "q_weight": float(self.weight[k]) if self.weight[k] > 0 else None}
                         for k in range(len(n))],
        })
        out["tests"] = geometry_tests(self.tests)
        if self.shells.shells is not None:
            out["shells"] = self.shells.report()
        out["shells_dropped"] = self.shells_dropped
        d = self.decision
        if self.fixed_q is None:  # q auto's decision, made for this render or read from the cache
            out["decision_cached"] = d.cached
        if d.predicted is not None:  # q auto's probe: the pilot ran only if it fit its budget
            out["pilot"] = dict({k: float(v) for k, v in d.predicted.items()}, ran=d.pilot_ran, cached=d.cached)
        return out
