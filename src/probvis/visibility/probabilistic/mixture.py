"""Adaptive mixture (beyond the 2013 paper): per penumbra pair, the mixture that minimises variance x cost.

The occlusion map estimates how often the pair's segments see each configuration (V_A, V_B) from the
neighbouring photons (with a Dirichlet(1/2) prior); test costs are estimated from the group sizes. The
candidates are shifted decompositions over a grid of probabilities with the shifts that minimise their
variance, and exact evaluation of both groups (A, then B only if A is visible) - so the choice is never much
worse than the baseline. See docs/adaptive.md for the derivation.
"""
import numpy as np
from numba import njit, prange

from .decomposition import CONFIGS, MODE_A, MODE_AB_BLOCKED, MODE_B, MODE_EXACT

P_GRID = np.array([(1 / 3, 1 / 3, 1 / 3), (0.4, 0.4, 0.2), (0.45, 0.45, 0.1), (0.25, 0.25, 0.5),
                   (0.5, 0.3, 0.2), (0.3, 0.5, 0.2), (0.6, 0.2, 0.2), (0.2, 0.6, 0.2), (0.7, 0.15, 0.15),
                   (0.15, 0.7, 0.15)])
PRIOR = 0.5
# X_i(VA, VB) of the shifted terms: V_A, V_B, complement product
_X = np.array([[va, vb, (1 - va) * (1 - vb)] for va, vb in CONFIGS], dtype=float)  # (4 configs, 3 terms)
_V = np.array([va * vb for va, vb in CONFIGS], dtype=float)
_VA = np.array([va for va, _ in CONFIGS], dtype=np.int64)
_VB = np.array([vb for _, vb in CONFIGS], dtype=np.int64)


@njit(cache=True, parallel=True, error_model="numpy")
def _choose(counts, size_a, size_b, verify_q, cdf, coef, mode, best):
    """Per pair the strategy with the least variance x cost; fills cdf, coef, mode and best (0 = exact)."""
    p_grid, prior, xs, vs, vas, vbs = P_GRID, PRIOR, _X, _V, _VA, _VB  # constants compiled in
    n_terms = 3
    for pr in prange(counts.shape[0]):
        total = 4 * prior
        for c in range(4):
            total += counts[pr, c]
        # verification: with probability q a segment is evaluated against its whole list instead (V_list, at the
        # exact strategy's cost) and gets the correction (V - V_list) / q, non-zero when the list says visible
        # (probability pi_11) and missed a blocker (rule of succession over the pair's photons): its variance and
        # its trace add to every strategy, and a strategy's own second moment and cost count with 1 - q
        vq = verify_q[pr]
        p11 = (counts[pr, 3] + prior) / total
        var_v = p11 / ((total - 4 * prior + 2.0) * vq) if vq > 0.0 else 0.0
        cost_v = vq * p11
        pi = np.empty(4)
        for c in range(4):
            pi[c] = (counts[pr, c] + prior) / total
        ex = np.zeros(n_terms)
        ev, ev2 = 0.0, 0.0
        for c in range(4):
            ev += pi[c] * vs[c]
            ev2 += pi[c] * vs[c] * vs[c]
            for k in range(n_terms):
                ex[k] += pi[c] * xs[c, k]
        # a group of n candidates costs n tests when visible, about (n + 1) / 2 when it blocks
        cost = np.empty((4, n_terms + 1))  # per configuration: the three terms, then exact evaluation
        for c in range(4):
            ca = size_a[pr] if vas[c] == 1 else (size_a[pr] + 1) / 2
            cb = size_b[pr] if vbs[c] == 1 else (size_b[pr] + 1) / 2
            cost[c, 0] = ca
            cost[c, 1] = cb
            cost[c, 2] = ca + (vas[c] == 0) * cb
            cost[c, 3] = ca + (vas[c] == 1) * cb
        exact_cost = 0.0
        for c in range(4):
            exact_cost += pi[c] * cost[c, 3]
        best_score = max((ev2 - ev * ev + var_v) * (exact_cost + cost_v), 1e-12)  # exact: the variance of V_list
        chosen = 0
        s_best = np.zeros(n_terms)
        s = np.empty(n_terms)
        sum_ex = ex[0] + ex[1] + ex[2]
        for g in range(p_grid.shape[0]):
            for k in range(n_terms):  # the shifts that minimise sum_i E[(X_i - s_i)^2] / p_i
                s[k] = ex[k] + p_grid[g, k] * (1.0 - sum_ex)
            second, cst = 0.0, 0.0
            for c in range(4):
                for k in range(n_terms):
                    dev = xs[c, k] - s[k]
                    second += pi[c] * dev * dev / p_grid[g, k]
                    cst += pi[c] * p_grid[g, k] * cost[c, k]
            second = (1.0 - vq) * second + vq * ev2
            score = (max(second - ev * ev, 0.0) + var_v) * ((1.0 - vq) * cst + vq * exact_cost + cost_v)
            if score < best_score * (1 - 1e-9):
                chosen, best_score = g + 1, score
                s_best[:] = s
        best[pr] = chosen
        if chosen == 0:
            mode[pr, 0], mode[pr, 1], mode[pr, 2] = MODE_EXACT, MODE_B, MODE_AB_BLOCKED
            cdf[pr, 0] = cdf[pr, 1] = cdf[pr, 2] = 1.0
            coef[pr, 0, 3] = 1.0  # V_A V_B
            continue
        p = p_grid[chosen - 1]
        mode[pr, 0], mode[pr, 1], mode[pr, 2] = MODE_A, MODE_B, MODE_AB_BLOCKED
        cdf[pr, 0], cdf[pr, 1], cdf[pr, 2] = p[0], p[0] + p[1], 1.0
        # term 0: (V_A - s0)/p0; term 1: (V_B - s1)/p1; term 2: ((1-V_A)(1-V_B) - s2)/p2
        coef[pr, 0, 0], coef[pr, 0, 1] = -s_best[0] / p[0], 1 / p[0]
        coef[pr, 1, 0], coef[pr, 1, 2] = -s_best[1] / p[1], 1 / p[1]
        coef[pr, 2, 0] = (1 - s_best[2]) / p[2]
        coef[pr, 2, 1] = coef[pr, 2, 2] = -1 / p[2]
        coef[pr, 2, 3] = 1 / p[2]


def choose(counts, size_a, size_b, verify_q=None):
    """Per pair: (cdf (n, 3), coefficients (n, 3, 4), modes (n, 3), chosen strategy index: 0 exact, 1.. grid).

    `counts` (n, 4) are photon counts per configuration (VA, VB) in CONFIGS order; `verify_q` (n,) the pair's
    verification probability (0 or None: not verified), whose correction term the model includes."""
    verify_q = np.zeros(len(counts)) if verify_q is None else np.asarray(verify_q, dtype=float)
    n = len(counts)
    cdf = np.zeros((n, 3))
    coef = np.zeros((n, 3, 4))
    mode = np.empty((n, 3), np.int8)
    best = np.empty(n, np.int64)
    _choose(np.ascontiguousarray(counts, dtype=float), np.asarray(size_a, dtype=float),
            np.asarray(size_b, dtype=float), verify_q, cdf, coef, mode, best)
    return cdf, coef, mode, best
