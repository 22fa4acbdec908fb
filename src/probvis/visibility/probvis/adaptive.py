"""Adaptive decomposition (beyond the seed): per penumbra pair, the mixture that minimises variance x cost.

The occlusion map estimates how often the pair's segments see each configuration (V_A, V_B) from the
neighbouring photons (with a Dirichlet(1/2) prior); test costs are estimated from the group sizes. The
candidates are shifted decompositions over a grid of probabilities with the shifts that minimise their
variance, and exact evaluation of both groups (A, then B only if A is visible) - so the choice is never much
worse than the baseline. See docs/adaptive.md for the derivation.
"""
import numpy as np

from .decomposition import CONFIGS, MODE_A, MODE_AB_BLOCKED, MODE_B, MODE_EXACT

P_GRID = np.array([(1 / 3, 1 / 3, 1 / 3), (0.4, 0.4, 0.2), (0.45, 0.45, 0.1), (0.25, 0.25, 0.5),
                   (0.5, 0.3, 0.2), (0.3, 0.5, 0.2), (0.6, 0.2, 0.2), (0.2, 0.6, 0.2), (0.7, 0.15, 0.15),
                   (0.15, 0.7, 0.15)])
PRIOR = 0.5
# X_i(VA, VB) of the shifted terms: V_A, V_B, complement product
_X = np.array([[va, vb, (1 - va) * (1 - vb)] for va, vb in CONFIGS], dtype=float)  # (4 configs, 3 terms)
_V = np.array([va * vb for va, vb in CONFIGS], dtype=float)


def _costs(size_a, size_b):
    """(n, 4 configs, 3 terms) expected triangle tests of each shifted term, and (n, 4) of exact evaluation:
    a group is tested to the end when visible, to about its middle when it blocks."""
    ca = np.stack([(size_a + 1) / 2, size_a], axis=1)  # by V_A = 0, 1
    cb = np.stack([(size_b + 1) / 2, size_b], axis=1)
    terms = np.empty((len(size_a), 4, 3))
    exact = np.empty((len(size_a), 4))
    for c, (va, vb) in enumerate(CONFIGS):
        terms[:, c, 0] = ca[:, va]
        terms[:, c, 1] = cb[:, vb]
        terms[:, c, 2] = ca[:, va] + (va == 0) * cb[:, vb]
        exact[:, c] = ca[:, va] + (va == 1) * cb[:, vb]
    return terms, exact


def choose(counts, size_a, size_b):
    """Per pair: (cdf (n, 3), coefficients (n, 3, 4), modes (n, 3), chosen strategy index: 0 exact, 1.. grid).

    `counts` (n, 4) are photon counts per configuration (VA, VB) in CONFIGS order."""
    n = len(counts)
    pi = (counts + PRIOR) / (counts.sum(axis=1, keepdims=True) + 4 * PRIOR)
    ex = pi @ _X  # (n, 3) expected X_i
    var_v = pi @ (_V ** 2) - (pi @ _V) ** 2
    cost_terms, cost_exact = _costs(size_a.astype(float), size_b.astype(float))
    best = np.full(n, 0)
    best_score = var_v * np.einsum("nc,nc->n", pi, cost_exact)  # exact: only the variance of V itself
    best_score = np.maximum(best_score, 1e-12)
    shifts_all = np.empty((len(P_GRID), n, 3))
    for g, p in enumerate(P_GRID):
        s = ex + p[None, :] * (1.0 - ex.sum(axis=1, keepdims=True))  # minimises sum_i E[(X_i - s_i)^2] / p_i
        shifts_all[g] = s
        dev = _X[None, :, :] - s[:, None, :]  # (n, 4, 3)
        second = np.einsum("nck,k->nc", dev ** 2, 1.0 / p)
        var = np.einsum("nc,nc->n", pi, second) - (pi @ _V) ** 2
        cost = np.einsum("nc,nck,k->n", pi, cost_terms, p)
        score = np.maximum(var, 0.0) * cost
        better = score < best_score * (1 - 1e-9)
        best = np.where(better, g + 1, best)
        best_score = np.where(better, score, best_score)
    cdf = np.zeros((n, 3))
    coef = np.zeros((n, 3, 4))
    mode = np.empty((n, 3), np.int8)
    mode[:] = (MODE_A, MODE_B, MODE_AB_BLOCKED)
    is_exact = best == 0
    mode[is_exact, 0] = MODE_EXACT
    cdf[is_exact] = 1.0
    coef[is_exact, 0, 3] = 1.0  # V_A V_B
    idx = np.flatnonzero(~is_exact)
    if len(idx):
        g = best[idx] - 1
        p = P_GRID[g]
        s = shifts_all[g, idx]
        cdf[idx] = np.cumsum(p, axis=1)
        # term 0: (V_A - s0)/p0; term 1: (V_B - s1)/p1; term 2: ((1-V_A)(1-V_B) - s2)/p2
        coef[idx, 0, 0], coef[idx, 0, 1] = -s[:, 0] / p[:, 0], 1 / p[:, 0]
        coef[idx, 1, 0], coef[idx, 1, 2] = -s[:, 1] / p[:, 1], 1 / p[:, 1]
        coef[idx, 2, 0] = (1 - s[:, 2]) / p[:, 2]
        coef[idx, 2, 1] = coef[idx, 2, 2] = -1 / p[:, 2]
        coef[idx, 2, 3] = 1 / p[:, 2]
    cdf[:, 2] = 1.0
    return cdf, coef, mode, best
