"""Probabilistic visibility (Billen et al. 2013) over the occlusion map's candidate lists.

Penumbra segments are evaluated by a decomposition of V = V_A V_B (see `decomposition`): one term chosen at
random, only the groups it needs tested. Lit, shadowed and unknown points are handled as by the occlusion map
with `penumbra="list"`, so the two converge to the same image and differ only in cost and noise.
"""
import time

import numpy as np

from ...errors import ProbvisError
from ...occlusion_map.map import NORMAL_COS
from ..occlusion_map import OcclusionMapVisibility
from . import adaptive as adaptive_choice
from .decomposition import MODE_EXACT
from .kernels import GROUP_COUNT, GROUP_RANDOM, GROUP_SOLID_ANGLE, configuration_counts, evaluate_segments, group_lists
from .power import power as power_decomposition
from .shifted import shifted as shifted_decomposition
from .standard import standard as standard_decomposition

GROUPINGS = {"solid-angle": GROUP_SOLID_ANGLE, "count": GROUP_COUNT, "random": GROUP_RANDOM}
ESTIMATOR_NAMES = ("standard", "shifted", "power", "adaptive")


class ProbvisVisibility(OcclusionMapVisibility):
    """`estimator`: standard | shifted | power | adaptive; `probabilities` (p1, p2, p3); `shifts` (α, β, γ);
    `power` n; `grouping`: solid-angle | count | random; `levels`: recursive subdivision depth (1 = A/B);
    `cells`: groups along the ray whose estimates are multiplied (1 = none). Other options: the occlusion
    map's (photons, neighbours, radius, adaptive photons, volumetric)."""

    name = "probvis"

    def __init__(self, estimator="standard", probabilities=None, shifts=None, power=8, grouping="solid-angle",
                 levels=1, cells=1, **map_options):
        if "penumbra" in map_options:
            raise ProbvisError("probvis always evaluates the penumbra over candidate lists; drop --penumbra")
        super().__init__(penumbra="list", **map_options)
        if estimator not in ESTIMATOR_NAMES:
            raise ProbvisError(f"unknown probvis estimator '{estimator}' (available: {', '.join(ESTIMATOR_NAMES)})")
        if grouping not in GROUPINGS:
            raise ProbvisError(f"grouping must be one of {', '.join(GROUPINGS)}, got '{grouping}'")
        for what, v in (("levels", levels), ("cells", cells)):
            if isinstance(v, bool) or int(v) != v or not 1 <= v <= 8:
                raise ProbvisError(f"{what} must be an integer from 1 to 8, got {v}")
        if estimator == "adaptive" and (levels != 1 or cells != 1 or probabilities or shifts):
            raise ProbvisError("the adaptive estimator chooses its own probabilities and shifts, on one A/B split")
        if shifts is not None and estimator != "shifted":
            raise ProbvisError("--shifts applies to the shifted estimator only")
        if power != 8 and estimator != "power":
            raise ProbvisError("--power applies to the power estimator only")
        p = (1 / 3, 1 / 3, 1 / 3) if probabilities is None else tuple(probabilities)
        try:
            if estimator == "standard":
                self.decomposition = standard_decomposition(p)
            elif estimator == "shifted":
                self.decomposition = shifted_decomposition(p, (1 / 3, 1 / 3, 1 / 3) if shifts is None else shifts)
            elif estimator == "power":
                self.decomposition = power_decomposition(power, p)
            else:
                self.decomposition = None
        except (ValueError, TypeError) as exc:
            raise ProbvisError(str(exc)) from None
        self.estimator, self.grouping = estimator, grouping
        self.levels, self.cells = int(levels), int(cells)
        self.probabilities, self.shifts, self.power = probabilities, shifts, power

    def options(self):
        opts = super().options()
        del opts["penumbra"]
        return {"estimator": self.estimator, "probabilities": self.probabilities, "shifts": self.shifts,
                "power": self.power, "grouping": self.grouping, "levels": self.levels, "cells": self.cells, **opts}

    def prepare(self, scene, bvh, emitters):
        super().prepare(scene, bvh, emitters)
        self._stats.update(term_selections=[0, 0, 0], exact_selections=0, group_balance=None, grouping_seconds=0.0,
                           adaptive_strategies=[0] * (len(adaptive_choice.P_GRID) + 1))
        self._balance = np.zeros(2)
        self._batches = 0

    def classify(self, points):
        case = super().classify(points)
        t0 = time.perf_counter()
        lk = self.lookup
        tris, bounds, balance = group_lists(self.scene.triangles, points.position[lk.first], lk.offsets, lk.tris, lk.n_rep,
                                            GROUPINGS[self.grouping], self.levels, self.cells, self.scene.seed)
        self.grouped, self.bounds = tris, bounds
        n_pairs = len(bounds)
        if self.decomposition is not None:
            d = self.decomposition
            self.cdf = np.repeat(np.cumsum(d.p)[None], n_pairs, axis=0)
            self.cdf[:, 2] = 1.0
            self.coef = np.repeat(d.coefficients()[None], n_pairs, axis=0)
            self.mode = np.repeat(d.mode[None], n_pairs, axis=0)
        else:
            self._choose_adaptive(lk, tris, bounds)
        used = balance.sum(axis=1) > 0
        self._balance += balance[used].sum(axis=0)
        self._stats["group_balance"] = {"solid_angle_share_A": self._balance[0] / max(self._balance.sum(), 1e-300)}
        self._stats["grouping_seconds"] += time.perf_counter() - t0
        return case

    def _choose_adaptive(self, lk, tris, bounds):
        n_rep = lk.n_rep
        counts = np.zeros((len(bounds), 4))
        nrm = self.normals[lk.first]
        ph = self.map.photons
        for e in range(self.scene.n_emitters):
            sl = slice(e * n_rep, (e + 1) * n_rep)
            counts[sl] = configuration_counts(lk.neighbours[e], nrm, ph.normal, ph.n_blockers, ph.start, ph.ray_tris,
                                              tris, bounds[sl], n_rep, NORMAL_COS)
        size_a = bounds[:, 1] - bounds[:, 0]
        size_b = bounds[:, 2] - bounds[:, 1]
        self.cdf, self.coef, self.mode, best = adaptive_choice.choose(counts, size_a, size_b)
        has_list = bounds[:, -1] > bounds[:, 0]
        st = self._stats["adaptive_strategies"]
        for k, c in enumerate(np.bincount(best[has_list], minlength=len(st))):
            st[k] += int(c)

    def evaluate_penumbra(self, query, idx):
        """Stochastic terms through the decomposition kernel; pairs whose mode is exact evaluation (adaptive)
        through the occlusion map's own list test, whose photon-frequency order finds a blocker sooner."""
        lk = self.lookup
        pair = query.emitter[idx].astype(np.int64) * lk.n_rep + lk.rep[query.point[idx]]
        exact = self.mode[pair, 0] == MODE_EXACT
        value = np.empty(len(idx))
        n_tri = np.empty(len(idx), dtype=np.int64)
        if exact.any():
            value[exact], n_tri[exact] = super().evaluate_penumbra(query, idx[exact])
        rest = ~exact
        if rest.any():
            sub, p = idx[rest], pair[rest]
            value[rest], n_tri[rest], n_cull, term = evaluate_segments(
                self.scene.triangles, self.orientation, self.fnormal, query.origin[sub], query.direction[sub],
                query.tmax[sub], p, query.key[sub], self.grouped, self.bounds, self.levels, self.cells, self.cdf,
                self.coef, self.mode)
            self._stats["culled_candidates"] += int(n_cull.sum())
            sel = np.bincount(term[term >= 0], minlength=3)
            for k in range(3):
                self._stats["term_selections"][k] += int(sel[k])
        self._stats["exact_selections"] += int(exact.sum())
        return value, n_tri
