"""The `occlusion-map` estimator: photons classify shading points; only penumbra points get shadow rays, and
those are tested against the point's candidate blockers (`penumbra="list"`) or the whole BVH ("bvh").

It renders through its own kernel (`kernel.shade_map`); `evaluate` is the same estimator on the staged path,
value for value (tested), kept as the readable reference and for the staged interface."""
import time
import warnings

import numba
import numpy as np

from ...accel import CandidateGeometry, occluded_segments, visibility_from_lists
from ...cycles import split_seconds
from ...errors import ProbvisError
from ...geometry import unit_normals
from ...rng import uniforms
from ...scene.scene import EMITTER_ENVIRONMENT
from ...shading import ShadedBatch
from ..base import (CASE_LIT, CASE_MASK, CASE_PENUMBRA, CASE_SHADOWED, CASE_UNKNOWN, CASE_VERIFIED, Aov, Option, Phase,
                    RenderPath, VisibilityEstimator, VisibilityResult)
from ..probabilistic.kernels import GroupedLists, TermTables
from . import kernel as mk
from . import verification
from .adaptive_photons import refine
from .components import BlockerGroups, blocker_groups, structure
from .map import OcclusionMap
from .photons import MAX_HITS, shoot_photons

DEFAULT_NEIGHBOURS = 32
PHOTONS_PER_CAMERA_SAMPLE = 0.5  # default photon budget: half a photon ray per camera sample ...
MIN_PHOTONS_DEFAULT = 100_000  # ... but at least this many
ADAPTIVE_SHARE = 0.5  # adaptive rounds may add up to this share of the first pass's photons
GROUP_COMPONENTS = 64  # a recorded blocker brings its whole connected component if that is this small
MAX_PHOTONS = 1 << 30
MAX_NEIGHBOURS = 1024

MAP_OPTIONS = (
    Option("photons", int, None, "photon rays of the first pass (default: half a ray per camera sample, at least "
                                 "100,000)", minimum=1, maximum=MAX_PHOTONS, warm_up=4096),
    Option("neighbours", int, DEFAULT_NEIGHBOURS, "photons looked up per shading point", minimum=1,
           maximum=MAX_NEIGHBOURS),
    Option("radius", float, None, "look-up radius (default: twice the median distance from a photon to its k-th "
                                  "neighbour)", check=lambda r: None if r > 0 else "must be positive"),
    Option("adaptive_photons", bool, False, "aim extra photons (up to half the first pass) at uncertain regions"),
    Option("volumetric", bool, True, "with candidate lists, skip closed meshes' triangles that face away from the "
                                     "segment's light end"),
    Option("verify", str, "auto", "how often the map's shortcuts (lit, shadowed, candidate lists) are checked "
                                  "against the whole scene with an unbiased correction term: auto (per pair from "
                                  "its photons), a probability from 0.001 to 1, or off (biased)",
           check=verification.parse_verify, metavar="auto|Q|off"),
    Option("cache", bool, True, "cache the scene's connected components and closed meshes' orientation on disk "
                                "($PROBVIS_CACHE_DIR, default ~/.cache/probvis)", warm_up=False),
)
MAP_PHASES = (
    Phase("photons", "prepare", "tracing the first pass of photon rays"),
    Phase("adaptive_photons", "prepare", "rounds of photons aimed at uncertain regions"),
    Phase("map_build", "prepare", "connected components, kd-trees"),
    Phase("lookup", "batch", "classifying shading points from their neighbouring photons"),
)
# the kernel's phases: its wall time split by the cycles each took (`probvis.cycles`)
KERNEL_PHASES = (
    Phase("sampling", "batch", "sampling the emitters of each shading point's cases"),
    Phase("term_choice", "batch", "drawing each penumbra segment's verification and decomposition term"),
    Phase("candidate_tests", "batch", "testing segments against their candidate lists or groups"),
    Phase("exact_traces", "batch", "tracing unknown (and, with penumbra=bvh, penumbra) segments against the scene"),
    Phase("verification_traces", "batch", "tracing verified segments against the scene"),
    Phase("film", "batch", "summing each camera sample's radiance"),
)
NO_GROUPS = GroupedLists(np.zeros(0, np.int32), np.zeros((1, 3), np.int64), 1, 1)
NO_TERMS = TermTables(np.ones((1, 3)), np.zeros((1, 3, 4)), np.zeros((1, 3), np.int8), False)
CASES_AOV = Aov("cases", "per pixel and emitter, the share of camera samples classified unknown, lit, shadowed "
                         "and penumbra", kind="cases")


class OcclusionMapVisibility(VisibilityEstimator):
    """Photons -> cases per shading point and emitter -> shadow rays only in the penumbra (and where too few
    photons fall to decide: 'unknown', tested against the whole scene)."""

    name = "occlusion-map"
    summary = "photons classify points as lit, shadowed or penumbra; shadow rays only in the penumbra"
    options = (Option("penumbra", str, "bvh", "test penumbra segments against the whole BVH (unbiased there) or "
                                              "only the candidate blockers of neighbouring shadow photons (fewer "
                                              "tests; without --verify, biased where the photons missed a "
                                              "blocker)",
                      choices=("bvh", "list")),) + MAP_OPTIONS
    phases = MAP_PHASES + KERNEL_PHASES
    aovs = (CASES_AOV,)
    penumbra_mode = None  # how the kernel evaluates penumbra segments (a subclass may fix it)

    @property
    def with_lists(self):
        return self.params.penumbra == "list"

    def photon_rays(self, scene, settings):
        """Photon rays of the first pass."""
        cam = scene.camera
        return self.params.photons or max(MIN_PHOTONS_DEFAULT,
                                          int(PHOTONS_PER_CAMERA_SAMPLE * cam.width * cam.height * settings.spp))

    def memory_estimate(self, scene, settings, batch_samples):
        rays = self.photon_rays(scene, settings) * (1 + ADAPTIVE_SHARE * self.params.adaptive_photons)
        k = self.params.neighbours
        return {
            # per ray: its MAX_HITS blocker slots; per photon (about 4 a ray): position, normal, ids, kd-tree
            "photons": int(rays * (MAX_HITS * 4 + 4 * (64 + 48))),
            # per camera sample and emitter: the k neighbours and their distances, then the candidate lists (and
            # per thread a table of counts by blocker group)
            "lookups": int(batch_samples * scene.n_emitters * (k * 16 + (k * MAX_HITS * 4 if self.with_lists else 0))
                           + (4 * scene.n_triangles * numba.get_num_threads() if self.with_lists else 0)),
        }

    @property
    def verify(self):
        """None (off), 'auto' or a fixed probability."""
        v = self.params.verify
        return None if v == "off" else v if v == "auto" else float(v)

    @classmethod
    def warm_ups(cls, options, largest=None):
        """Without radius, a length at the real scene's scale: the warm-up scene takes its automatic one."""
        return [{k: v for k, v in run.items() if k != "radius"} for run in super().warm_ups(options, largest)]

    def prepare(self, scene, bvh, emitters, settings, integrator):
        super().prepare(scene, bvh, emitters, settings, integrator)
        self.tally = verification.Tally()
        p = self.params
        lo, hi = scene.bounds()
        diagonal = float(np.linalg.norm(hi - lo))
        if p.radius is not None and p.radius > diagonal:
            raise ProbvisError(f"radius {p.radius:g} is larger than the scene (diagonal {diagonal:.4g}): every photon "
                               "would be every point's neighbour; use a radius well below the scene's size")
        if p.radius is not None and p.radius < 1e-9 * diagonal:
            raise ProbvisError(f"radius {p.radius:g} is below a billionth of the scene (diagonal {diagonal:.4g}): "
                               "no photon would be any point's neighbour; leave it out for the default")
        # an envmap has no closed-form irradiance: its "lit" points are sampled and tested like unknown ones
        env = scene.environment
        self.no_closed_form = ([] if env is None or env.constant else
                               np.flatnonzero(scene.emitter_kind == EMITTER_ENVIRONMENT))
        n = self.photon_rays(scene, settings)
        t_geom = time.perf_counter()
        self.fnormal = unit_normals(scene.triangles)
        n_tri = scene.n_triangles
        self.orientation = np.zeros(n_tri, np.int8)
        if self.with_lists:
            st = structure(scene, p.cache)
            if p.volumetric:  # only where the list holds the whole component, so its exit face too
                whole = np.bincount(st.label)[st.label] <= GROUP_COMPONENTS
                self.orientation = np.where(whole, st.orientation, 0).astype(np.int8)
            groups = blocker_groups(st.label, st.n_components, GROUP_COMPONENTS)
        else:  # lists are not used: each triangle stands for itself
            groups = BlockerGroups.singletons(n_tri)
        self.seconds["map_build"] += time.perf_counter() - t_geom
        with self.timed("photons"):
            photons = shoot_photons(scene, bvh, emitters, n, settings.seed)
        first = len(photons)
        rounds, radius = [], p.radius
        with self.timed("adaptive_photons"):
            if p.adaptive_photons and len(photons):
                photons, radius, rounds = refine(scene, bvh, emitters, photons, p.neighbours, groups, radius,
                                                 int(ADAPTIVE_SHARE * n), settings.seed)
        with self.timed("map_build"):
            self.map = OcclusionMap(photons, scene.n_emitters, p.neighbours, groups, radius)
        if len(photons) == 0:
            warnings.warn(f"occlusion map: no photon of scene '{scene.name}' hit anything; every point is "
                          "'unknown' and tested against the whole scene (exact visibility)", stacklevel=2)
        elif p.radius is None and self.map.radius > diagonal:
            warnings.warn(f"occlusion map: the automatic radius {self.map.radius:.4g} is larger than the scene "
                          f"(diagonal {diagonal:.4g}): {len(photons)} photons are too few for neighbours "
                          f"{p.neighbours}, so every photon is every point's neighbour; give more photons or fewer "
                          "neighbours", stacklevel=2)
        shadow = photons.shadow
        self._stats = {
            "photon_rays": photons.rays, "photon_rays_first_pass": n, "photons": len(photons),
            "photons_first_pass": first, "light_photons": int((~shadow).sum()), "shadow_photons": int(shadow.sum()),
            "radius": self.map.radius, "neighbours": p.neighbours,
            "photon_tests": {"triangle": photons.triangle_tests, "node": photons.node_tests},
            "closed_triangles": int((self.orientation != 0).sum()),
            "adaptive_rounds": rounds,
            "list_length": {"mean": None, "max": None, "penumbra_pairs": 0},
            "culled_candidates": 0, "penumbra_shadow_rays": 0, "unknown_shadow_rays": 0,
        }
        self._list_sum = 0
        self.candidates = CandidateGeometry(scene.triangles, self.orientation, self.fnormal)
        self._rows = np.empty((numba.config.NUMBA_NUM_THREADS, 2, 256, 13))  # the kernel's gathered candidates

    def render_path(self):
        """Its own kernel (`kernel.shade_map`), value for value what the staged path renders."""
        return RenderPath.OWN_KERNEL

    def kernel_inputs(self):
        """The decomposition's groups and terms for the kernel, and how it evaluates penumbra segments."""
        return NO_GROUPS, NO_TERMS, mk.PENUMBRA_LIST if self.with_lists else mk.PENUMBRA_BVH

    def shade(self, batch):
        lk = self.lookup
        groups, terms, penumbra = self.kernel_inputs()
        q = self.q if self.verify is not None else np.zeros((1, 1))
        lists = mk.PairLists(lk.rep.astype(np.int64), lk.n_rep, lk.offsets, lk.tris, q, penumbra,
                             self.verify is not None)
        longest = int(np.diff(lk.offsets).max()) if len(lk.offsets) > 1 else 0
        if self._rows.shape[2] < longest:  # room for the longest list, per thread
            self._rows = np.empty((numba.config.NUMBA_NUM_THREADS, 2, max(longest, 2 * self._rows.shape[2]), 13))
        t0 = time.perf_counter()
        radiance, counts, n_seg, counters, sums, cycles = mk.shade_map(
            self.integrator.scene_arrays, self.emitters.arrays, self.bvh.arrays, batch, self.candidates, lists, groups,
            terms, self._rows)
        for name, sec in zip(mk.PHASE_NAMES, split_seconds(time.perf_counter() - t0, cycles)):
            self.seconds[name] += sec
        self.add_counters(counters)
        for case, n, n_ver, base in ((CASE_LIT, mk.LIT_SEGMENTS, mk.LIT_VERIFIED, mk.LIT_SUMS),
                                     (CASE_SHADOWED, mk.SHADOWED_SEGMENTS, mk.SHADOWED_VERIFIED, mk.SHADOWED_SUMS),
                                     (CASE_PENUMBRA, mk.PENUMBRA_SEGMENTS, mk.PENUMBRA_VERIFIED, mk.PENUMBRA_SUMS)):
            if counters[n_ver]:
                self.tally.add_sums(case, counters[n], counters[n_ver], sums[base + mk.MISMATCH],
                                    sums[base + mk.MISMATCH2], sums[base + mk.Q_SUM],
                                    counters[mk.PENUMBRA_MEASURED] if case == CASE_PENUMBRA else None)
        return ShadedBatch(radiance, counts, n_seg)

    def add_counters(self, counters):
        """The kernel's counters into the stats."""
        st = self._stats
        st["culled_candidates"] += int(counters[mk.CULLED])
        st["penumbra_shadow_rays"] += int(counters[mk.PENUMBRA_RAYS])
        st["unknown_shadow_rays"] += int(counters[mk.UNKNOWN_RAYS])

    def classify(self, points):
        with self.timed("lookup"):
            return self._classify(points)

    def _classify(self, points):
        tri = points.triangle
        shaded = tri >= 0
        g = self.fnormal[np.maximum(tri, 0)]
        g = np.where((np.einsum("ij,ij->i", g, points.normal) < 0)[:, None], -g, g)
        g[~shaded] = 0.0
        self.normals = g  # geometric normals on the shading normal's side, zero where not shaded
        with_lists = self.with_lists
        self.lookup = self.map.lookup(points.position, g, with_lists=with_lists)
        lk, st = self.lookup, self._stats
        for e in self.no_closed_form:
            lk.case[lk.case[:, e] == CASE_LIT, e] = CASE_UNKNOWN
        pen = lk.case == CASE_PENUMBRA
        self.cases = lk.case
        if self.verify is not None:
            if self.verify == "auto":
                self.q = verification.auto_q(lk.case, lk.photons[lk.rep], lk.unseen[lk.rep], self.tally.floors())
            else:
                self.q = np.full(lk.case.shape, self.verify)
            self.cases = verification.flag_verified(lk.case, self.q, points.key)
            self.tally.add_pairs(lk.case, self.cases)
        ll = st["list_length"]
        ll["penumbra_pairs"] += int(pen.sum())
        if with_lists:
            m = lk.case.shape[0]
            lo, hi = lk.range(np.arange(m)[:, None], np.arange(self.scene.n_emitters)[None, :])
            lengths = (hi - lo)[pen]
            self._list_sum += int(lengths.sum())
            ll["max"] = max(ll["max"] or 0, int(lengths.max()) if len(lengths) else 0)
            ll["mean"] = self._list_sum / max(1, ll["penumbra_pairs"])
        return self.cases

    def segment_lists(self, query, idx):
        """Candidate-list range [lo, hi) of each segment in idx."""
        return self.lookup.range(query.point[idx], query.emitter[idx])

    def _trace(self, query, idx, n_node, n_tri):
        """Exact visibility of segments idx against the whole scene; their tests are added to the counts."""
        occ, a, b = occluded_segments(self.bvh, query.origin[idx], query.direction[idx], query.tmax[idx],
                                      query.point[idx])
        n_node[idx] += a
        n_tri[idx] += b
        return 1.0 - occ

    def evaluate(self, query):
        n = len(query.tmax)
        value = np.ones(n)
        n_node = np.zeros(n, np.int32)
        n_tri = np.zeros(n, np.int32)
        flagged = self.cases[query.point, query.emitter]
        case = flagged & CASE_MASK
        on_bvh = (case == CASE_UNKNOWN) | ((case == CASE_PENUMBRA) if not self.with_lists else False)
        idx = np.flatnonzero(on_bvh)
        if len(idx):
            value[idx] = self._trace(query, idx, n_node, n_tri)
        self._stats["unknown_shadow_rays"] += int((case == CASE_UNKNOWN).sum())
        self._stats["penumbra_shadow_rays"] += int((case == CASE_PENUMBRA).sum())
        if self.with_lists:
            idx = np.flatnonzero(case == CASE_PENUMBRA)
            if len(idx):
                verified = traced = np.zeros(len(idx), bool)
                if self.verify is not None:
                    q = self.q[query.point[idx], query.emitter[idx]]
                    verified = uniforms(query.key[idx], verification.SEGMENT_DIM) < q
                    traced = verified & (q >= 1.0)  # V_list + (V - V_list) / 1 = V: the trace alone
                listed = idx[~traced]
                if len(listed):
                    value[listed], n_tri[listed] = self.evaluate_penumbra(query, listed, verified[~traced])
                if traced.any():
                    value[idx[traced]] = self._trace(query, idx[traced], n_node, n_tri)
                if self.verify is not None:
                    self._verify_lists(query, listed, verified[~traced], value, n_node, n_tri, len(idx),
                                       float(q[traced].sum()), int(traced.sum()))
        for c, approx in ((CASE_LIT, 1.0), (CASE_SHADOWED, 0.0)):  # verified pairs: the correction terms
            idx = np.flatnonzero(flagged == (c | CASE_VERIFIED))
            if len(idx):
                q = self.q[query.point[idx], query.emitter[idx]]
                mismatch = self._trace(query, idx, n_node, n_tri) - approx
                value[idx] = mismatch / q
                self.tally.add_segments(c, len(idx), mismatch, q)
        return VisibilityResult(value, n_node, n_tri)

    def _verify_lists(self, query, idx, verified, value, n_node, n_tri, n_total, q_traced, n_traced):
        """Add B (V - V_list) / q to the penumbra segments idx whose draw B (`verified`) came up: their values are
        V_list (`evaluate_penumbra` tests the whole list of a verified segment), and a listed blocker really
        blocks (V <= V_list), so the correction is non-zero only where the list says visible: only those are
        traced. Of the case's `n_total` segments, `n_traced` more (q = 1, q summing to `q_traced`) were traced
        alone."""
        ver = idx[verified]
        q = self.q[query.point[ver], query.emitter[ver]]
        mismatch = np.zeros(len(ver))
        open_ = value[ver] == 1.0
        if open_.any():
            mismatch[open_] = self._trace(query, ver[open_], n_node, n_tri) - 1.0
        value[ver] += mismatch / q
        self.tally.add_segments(CASE_PENUMBRA, n_total, mismatch, q, n_traced, q_traced)

    def evaluate_penumbra(self, query, idx, verified):
        """Visibility and triangle tests of the penumbra segments idx against their candidate lists (a subclass
        may estimate the lists' visibility of the segments not `verified` instead)."""
        lo, hi = self.segment_lists(query, idx)
        vis, n_tri, n_cull = visibility_from_lists(self.scene.triangles, self.orientation, self.fnormal,
                                                   query.origin[idx], query.direction[idx], query.tmax[idx], lo, hi,
                                                   self.lookup.tris)
        self._stats["culled_candidates"] += int(n_cull.sum())
        return vis, n_tri

    def memory_bytes(self):
        ph = self.map.photons
        trees = sum(t.data.nbytes + t.indices.nbytes for t in self.map.trees if t is not None)
        groups = sum(a.nbytes for a in self.map.groups)  # group per triangle, CSR offsets, triangle ids
        return {"photons": sum(a.nbytes for a in (ph.position, ph.normal, ph.emitter, ph.n_blockers, ph.start,
                                                 ph.ray_tris)), "kd-trees": trees, "blocker groups": groups}

    def stats(self):
        return {**super().stats(), **self._stats, "verification": self.tally.stats(self.params.verify)}
