"""The `probvis` estimator: probabilistic visibility (Billen et al. 2013) over the occlusion map's candidate lists.

Penumbra segments are evaluated by a decomposition of V = V_A V_B (see `decomposition`): one term chosen at
random, only the groups it needs tested. Lit, shadowed and unknown points are handled as by the occlusion map
with `penumbra="list"`, so the two converge to the same image and differ only in cost and noise. A segment
drawn for verification is evaluated against its whole list instead, whose exact value the correction needs
anyway: (1 - B) X + B (V_list + (V - V_list) / q) has expectation V for any estimate X of V_list.
"""
import warnings

import numpy as np

from ...errors import ProbvisError
from ..base import CASE_PENUMBRA, Option, Phase
from ..occlusion_map.estimator import CASES_AOV, KERNEL_PHASES, MAP_OPTIONS, MAP_PHASES, OcclusionMapVisibility
from ..occlusion_map import kernel as mk
from ..occlusion_map import verification
from ..occlusion_map.map import NORMAL_COS
from . import mixture
from .decomposition import MODE_EXACT
from .kernels import (GROUP_COUNT, GROUP_RANDOM, GROUP_SOLID_ANGLE, GroupedLists, TermTables, configuration_counts,
                      evaluate_segments, group_lists)
from .power import power as power_decomposition
from .shifted import shifted as shifted_decomposition
from .standard import standard as standard_decomposition

GROUPINGS = {"solid-angle": GROUP_SOLID_ANGLE, "count": GROUP_COUNT, "random": GROUP_RANDOM}
DECOMPOSITIONS = ("standard", "shifted", "power", "adaptive")
MAX_REACH = 1e12  # the largest |estimate| of one segment allowed (as of a plug-in's): beyond, images overflow
NOISY_REACH = 100  # above, a warning: such terms make an image far noisier than exact visibility's
MAX_LEVELS = 5  # the shifted decomposition's reach at 5 levels is 2e11; at 6, no decomposition's is below 1e12
MAX_POWER = 64  # (V_A + V_B)^n / (2^n - 2): beyond this the terms lose all precision


class ProbabilisticVisibility(OcclusionMapVisibility):
    """Occlusion-map cases; penumbra segments by one random term of a decomposition of V_A V_B."""

    name = "probvis"
    summary = "probabilistic visibility (Billen et al. 2013): one random term of V = V_A V_B per penumbra segment"
    options = (
        Option("estimator", str, "standard", "decomposition of V = V_A V_B: the paper's standard and shifted ones, "
                                             "the power decomposition, or the adaptive mixture",
               choices=DECOMPOSITIONS),
        Option("probabilities", tuple, None, "term probabilities p1,p2,p3 (default 1/3 each)", count=3,
               minimum=0.0, maximum=1.0, metavar="P1,P2,P3"),
        Option("shifts", tuple, None, "shifts α,β,γ of the shifted decomposition, summing to 1 (default 1/3 each)",
               count=3, metavar="A,B,G"),
        Option("power", int, 8, "exponent n of the power decomposition", minimum=2, maximum=MAX_POWER),
        Option("grouping", str, "solid-angle", "how a candidate list is split into A and B",
               choices=tuple(GROUPINGS)),
        Option("levels", int, 1, "recursive subdivision depth (1: one A/B split)", minimum=1, maximum=MAX_LEVELS),
        Option("cells", int, 1, "groups along the ray whose estimates are multiplied (1: none)", minimum=1,
               maximum=8),
    ) + MAP_OPTIONS
    phases = MAP_PHASES + (Phase("grouping", "batch", "splitting candidate lists into groups, choosing mixtures"),
                           ) + KERNEL_PHASES
    aovs = (CASES_AOV,)

    @property
    def with_lists(self):
        return True

    def __init__(self, **options):
        super().__init__(**options)
        p = self.params
        given = [name for name, value in (("levels", p.levels != 1), ("cells", p.cells != 1),
                                          ("probabilities", p.probabilities), ("shifts", p.shifts)) if value]
        if p.estimator == "adaptive" and given:
            raise ProbvisError(f"{' and '.join(given)} {'does' if len(given) == 1 else 'do'} not apply to the adaptive "
                               "estimator, which chooses its own probabilities and shifts on one A/B split: leave "
                               f"{'it' if len(given) == 1 else 'them'} out, or choose another estimator")
        if p.shifts is not None and p.estimator != "shifted":
            raise ProbvisError("shifts apply to the shifted estimator only")
        if p.power != 8 and p.estimator != "power":
            raise ProbvisError("power applies to the power estimator only")
        probs = (1 / 3, 1 / 3, 1 / 3) if p.probabilities is None else p.probabilities
        try:
            if p.estimator == "standard":
                self.decomposition = standard_decomposition(probs)
            elif p.estimator == "shifted":
                self.decomposition = shifted_decomposition(probs, (1 / 3, 1 / 3, 1 / 3) if p.shifts is None
                                                           else p.shifts)
            elif p.estimator == "power":
                self.decomposition = power_decomposition(p.power, probs)
            else:
                self.decomposition = None
        except (ValueError, TypeError) as exc:
            raise ProbvisError(str(exc)) from None
        reach = self.decomposition.reach(p.levels, p.cells) if self.decomposition is not None else 1.0
        if reach > MAX_REACH:
            size = f"±{reach:.2g}" if np.isfinite(reach) else "beyond a double's range"
            raise ProbvisError(f"levels {p.levels} and cells {p.cells}: one segment's estimate could reach {size} "
                               f"(each level's 1/p weights multiply, and the cells' estimates), beyond {MAX_REACH:g}; "
                               "lower levels or cells")
        self.reach = reach

    def prepare(self, scene, bvh, emitters, settings, integrator):
        super().prepare(scene, bvh, emitters, settings, integrator)
        p = self.params
        if self.reach > NOISY_REACH:
            warnings.warn(f"levels {p.levels} and cells {p.cells}: one segment's estimate may reach "
                          f"±{self.reach:.2g}, so the image, though unbiased, is far noisier than exact visibility's "
                          "(the paper's negative finding for deep subdivision); levels 1 and cells 1 are the defaults",
                          stacklevel=2)
        self._stats.update(term_selections=[0, 0, 0], exact_selections=0, group_balance=None,
                           adaptive_strategies=[0] * (len(mixture.P_GRID) + 1))
        d = self.decomposition
        if d is not None:  # one row of term tables for every pair
            cdf = np.cumsum(d.p)[None]
            cdf[:, 2] = 1.0
            self.terms = TermTables(cdf, d.coefficients()[None], d.mode[None], False)
        self._balance = np.zeros(2)
        self._batches = 0

    def classify(self, points):
        case = super().classify(points)
        with self.timed("grouping"):
            self._group(points)
        return case

    def _group(self, points):
        lk = self.lookup
        p = self.params
        q = self._pair_q(lk)  # pairs whose segments are all verified with q = 1 never use their groups
        tris, bounds, balance = group_lists(self.scene.triangles, points.position[lk.first], lk.offsets, lk.tris,
                                            self.map.groups.group, lk.n_rep, GROUPINGS[p.grouping], p.levels,
                                            p.cells, self.render_settings.seed, None if q is None else q >= 1.0)
        self.groups = GroupedLists(tris, bounds, p.levels, p.cells)
        if self.decomposition is None:
            self.terms = self._choose_adaptive(lk, tris, bounds)
        used = balance.sum(axis=1) > 0
        self._balance += balance[used].sum(axis=0)
        self._stats["group_balance"] = {"solid_angle_share_A": self._balance[0] / max(self._balance.sum(), 1e-300)}

    def _choose_adaptive(self, lk, tris, bounds):
        n_rep = lk.n_rep
        counts = np.zeros((len(bounds), 4))
        nrm = self.normals[lk.first]
        ph = self.map.photons
        for e in range(self.scene.n_emitters):
            sl = slice(e * n_rep, (e + 1) * n_rep)
            counts[sl] = configuration_counts(lk.neighbours[e], nrm, ph.arrays, tris, bounds[sl], n_rep, NORMAL_COS)
        size_a = bounds[:, 1] - bounds[:, 0]
        size_b = bounds[:, 2] - bounds[:, 1]
        cdf, coef, mode, best = mixture.choose(counts, size_a, size_b, self._pair_q(lk))
        has_list = bounds[:, -1] > bounds[:, 0]
        st = self._stats["adaptive_strategies"]
        for k, c in enumerate(np.bincount(best[has_list], minlength=len(st))):
            st[k] += int(c)
        return TermTables(cdf, coef, mode, True)

    def _pair_q(self, lk):
        """Verification probability of each (emitter, look-up) pair of the penumbra, in pair order."""
        if self.verify is None:
            return None
        if self.verify == "auto":
            q = lk.unseen.T.reshape(-1)
            return np.clip(np.maximum(q, self.tally.floors().get(CASE_PENUMBRA, 0.0)), verification.Q_MIN, 1.0)
        return np.full(lk.n_rep * self.scene.n_emitters, self.verify)

    def kernel_inputs(self):
        return self.groups, self.terms, mk.PENUMBRA_TERMS

    def add_counters(self, counters):
        super().add_counters(counters)
        for k in range(3):
            self._stats["term_selections"][k] += int(counters[mk.TERM_0 + k])
        self._stats["exact_selections"] += int(counters[mk.EXACT_SELECTIONS])

    def evaluate_penumbra(self, query, idx, verified):
        """Stochastic terms through the decomposition kernel; verified segments, and pairs whose mode is exact
        evaluation (adaptive), through the occlusion map's own list test, whose photon-frequency order finds a
        blocker sooner."""
        lk = self.lookup
        pair = query.emitter[idx].astype(np.int64) * lk.n_rep + lk.rep[query.point[idx]]
        exact = self.terms.mode[pair if self.terms.per_pair else np.zeros_like(pair), 0] == MODE_EXACT
        whole = exact | verified
        value = np.empty(len(idx))
        n_tri = np.empty(len(idx), dtype=np.int64)
        if whole.any():
            value[whole], n_tri[whole] = super().evaluate_penumbra(query, idx[whole], verified[whole])
        rest = ~whole
        if rest.any():
            sub = idx[rest]
            value[rest], n_tri[rest], n_cull, term = evaluate_segments(
                self.candidates, query.origin[sub], query.direction[sub], query.tmax[sub], pair[rest],
                query.key[sub], self.groups, self.terms)
            self._stats["culled_candidates"] += int(n_cull.sum())
            sel = np.bincount(term[term >= 0], minlength=3)
            for k in range(3):
                self._stats["term_selections"][k] += int(sel[k])
        self._stats["exact_selections"] += int(exact.sum())
        return value, n_tri
