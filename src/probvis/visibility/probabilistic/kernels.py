"""Numba kernels of probabilistic visibility: grouping of candidate lists and stochastic evaluation.

A penumbra pair's candidate list is reordered into `cells * 2**levels` consecutive leaves: `cells` groups
along the ray (by distance from the point), each split recursively `levels` times into A and B. With
cells = levels = 1 that is the 2013 paper's single split into A and B.
"""
import math
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from ...accel import CHUNK, first_blocker, ray_setup
from ...parallel import over_lanes
from ...rng import mix64, uniform
from .decomposition import MODE_A, MODE_AB_BLOCKED, MODE_B, MODE_BOTH, MODE_EXACT

GROUP_SOLID_ANGLE, GROUP_COUNT, GROUP_RANDOM = 0, 1, 2


@njit(cache=True, error_model="numpy", inline="always")
def solid_angle(triangles, t, px, py, pz):
    """Solid angle of triangle t seen from p (Van Oosterom and Strackee 1983)."""
    ax, ay, az = triangles[t, 0, 0] - px, triangles[t, 0, 1] - py, triangles[t, 0, 2] - pz
    bx, by, bz = triangles[t, 1, 0] - px, triangles[t, 1, 1] - py, triangles[t, 1, 2] - pz
    cx, cy, cz = triangles[t, 2, 0] - px, triangles[t, 2, 1] - py, triangles[t, 2, 2] - pz
    la = math.sqrt(ax * ax + ay * ay + az * az)
    lb = math.sqrt(bx * bx + by * by + bz * bz)
    lc = math.sqrt(cx * cx + cy * cy + cz * cz)
    num = ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)
    den = (la * lb * lc + (ax * bx + ay * by + az * bz) * lc + (ax * cx + ay * cy + az * cz) * lb
           + (bx * cx + by * cy + bz * cz) * la)
    return 2.0 * abs(math.atan2(num, den))


SMALL_SORT = 64  # units of one group ranked by comparisons below this many (no allocation), by mergesort above


@njit(cache=True, error_model="numpy", inline="always")
def _split(order, weight, leaf, lo, hi, method, key, level, srt, rank_key):
    """Split units order[lo:hi] of one group in two: leaf id bit 0 for A, 1 for B. `srt` and `rank_key` are
    scratch."""
    n = hi - lo
    if method == GROUP_SOLID_ANGLE:  # largest first, each to the group with less solid angle so far
        if n <= SMALL_SORT:
            # each unit's place in a stable descending order (NaN last, as NumPy sorts -weight): the units that
            # come before it, counted without branches (a sort's comparisons mispredict on random weights)
            for a in range(n):
                w = weight[order[lo + a]]
                rank_key[a] = w if w == w else -1.0
            for a in range(n):
                ka = rank_key[a]
                r = 0
                for b in range(n):
                    r += (rank_key[b] > ka) | ((rank_key[b] == ka) & (b < a))
                srt[r] = order[lo + a]
        else:
            w = np.empty(n)
            for a in range(n):
                w[a] = -weight[order[lo + a]]
            by_weight = np.argsort(w, kind="mergesort")
            for a in range(n):
                srt[a] = order[lo + by_weight[a]]
        sa, sb = 0.0, 0.0
        for a in range(n):  # selects, not branches: which group a unit joins is a coin toss to the predictor
            e = srt[a]
            w = weight[e]
            to_b = not sa <= sb
            leaf[e] = leaf[e] * 2 + to_b
            sa = sa if to_b else sa + w
            sb = sb + w if to_b else sb
    elif method == GROUP_COUNT:  # alternate in list (frequency) order
        for a in range(n):
            e = order[lo + a]
            leaf[e] = leaf[e] * 2 + (a % 2)
    else:
        for a in range(n):
            e = order[lo + a]
            coin = mix64(key + np.uint64(e * 64 + level)) >> np.uint64(63)
            leaf[e] = leaf[e] * 2 + np.int64(coin)


def group_lists(triangles, pos, offsets, tris, unit, n_rep, method, levels, cells, seed, skip=None):
    """Reorder each pair's candidates into leaves (see module docstring); returns the reordered triangle ids,
    leaf boundaries (pairs, leaves + 1) as absolute positions, and each pair's solid angle in A and B. Pairs
    `skip` marks (none are used split: all their segments are verified with certainty) keep their list whole,
    in the first leaf.

    The blockers split are the list's blocker groups (`unit[t]`: the small connected component a recorded
    triangle stands for, or the triangle alone), which stand in the list as runs of consecutive triangles: a
    city's box goes to A or B whole, so the volumetric culling of its faces stays regular along the group. A
    serial kernel over the pairs runs on the thread budget (`over_lanes`)."""
    n_pairs = offsets.shape[0] - 1
    n_leaves = cells * (1 << levels)
    out = (np.empty_like(tris), np.empty((n_pairs, n_leaves + 1), np.int64), np.zeros((n_pairs, 2)))
    skip = np.zeros(n_pairs, np.bool_) if skip is None else skip
    config = (np.int64(n_rep), np.int64(method), np.int64(levels), np.int64(cells), np.int64(seed))
    over_lanes(lambda lane, lanes: _group_pairs(triangles, pos, (offsets, tris, unit, skip), config, lane, lanes,
                                                out), n_pairs)
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def _group_pairs(triangles, pos, lists, config, lane, lanes, result):
    """Pairs lane, lane + lanes, ... of `group_lists`, into `result` (its reordered ids, bounds and balance);
    `lists` are its (offsets, tris, unit, skip), `config` its (n_rep, method, levels, cells, seed). Scratch is
    allocated once for the longest list."""
    offsets, tris, unit, skip = lists
    n_rep, method, levels, cells, seed = config
    out, bounds, balance = result
    n_pairs = offsets.shape[0] - 1
    n_leaves = cells * (1 << levels)
    n_max = 0
    for pr in range(lane, n_pairs, lanes):
        n_max = max(n_max, offsets[pr + 1] - offsets[pr])
    first = np.empty(n_max + 1, np.int64)  # runs of one blocker group: units lo + first[u] .. lo + first[u + 1]
    weight = np.empty(n_max)
    leaf = np.empty(n_max, np.int64)
    order = np.empty(n_max, np.int64)
    srt = np.empty(n_max, np.int64)
    rank_key = np.empty(min(n_max, SMALL_SORT))
    counts = np.empty(n_leaves + 1, np.int64)
    for pr in range(lane, n_pairs, lanes):
        lo, hi = offsets[pr], offsets[pr + 1]
        n = hi - lo
        if skip[pr]:
            for a in range(lo, hi):
                out[a] = tris[a]
            bounds[pr, 0] = lo
            for g in range(1, n_leaves + 1):
                bounds[pr, g] = hi
            continue
        i = pr % n_rep
        px, py, pz = pos[i, 0], pos[i, 1], pos[i, 2]
        n_units = 0
        for a in range(n):
            t = tris[lo + a]
            if a == 0 or unit[t] != unit[tris[lo + a - 1]]:
                first[n_units] = a
                weight[n_units] = 0.0
                leaf[n_units] = 0
                n_units += 1
            weight[n_units - 1] += solid_angle(triangles, t, px, py, pz)
        first[n_units] = n
        if cells > 1:  # cells: equal counts of units by distance from the point (their first triangle's centroid)
            dist = np.empty(n_units)
            for u in range(n_units):
                t = tris[lo + first[u]]
                cx = (triangles[t, 0, 0] + triangles[t, 1, 0] + triangles[t, 2, 0]) / 3.0 - px
                cy = (triangles[t, 0, 1] + triangles[t, 1, 1] + triangles[t, 2, 1]) / 3.0 - py
                cz = (triangles[t, 0, 2] + triangles[t, 1, 2] + triangles[t, 2, 2]) / 3.0 - pz
                dist[u] = cx * cx + cy * cy + cz * cz
            by_dist = np.argsort(dist, kind="mergesort")
            for u in range(n_units):
                leaf[by_dist[u]] = (u * cells) // max(n_units, 1)
        key = mix64(np.uint64(seed) + np.uint64(pr) * np.uint64(0x9E3779B97F4A7C15))
        for level in range(levels):
            # units grouped by leaf, list order inside each (a stable counting sort; at the top of one cell,
            # one leaf in list order)
            counts[:] = 0
            for u in range(n_units):
                counts[leaf[u] + 1] += 1
            for g in range(n_leaves):
                counts[g + 1] += counts[g]
            for u in range(n_units):
                order[counts[leaf[u]]] = u
                counts[leaf[u]] += 1
            a = 0
            while a < n_units:
                b = a
                while b < n_units and leaf[order[b]] == leaf[order[a]]:
                    b += 1
                _split(order, weight, leaf, a, b, method, key, level, srt, rank_key)
                a = b
            if level == 0:
                for u in range(n_units):
                    balance[pr, leaf[u] % 2] += weight[u]
        # leaves in order, the frequency order kept inside each leaf (a stable sort by leaf)
        counts[:] = 0
        for u in range(n_units):
            counts[leaf[u] + 1] += first[u + 1] - first[u]
        for g in range(n_leaves):
            counts[g + 1] += counts[g]
            bounds[pr, g] = lo + counts[g]
        bounds[pr, n_leaves] = hi
        for u in range(n_units):
            for a in range(first[u], first[u + 1]):
                out[lo + counts[leaf[u]]] = tris[lo + a]
                counts[leaf[u]] += 1


class GroupedLists(NamedTuple):
    """The candidate lists of a batch's pairs, each reordered into `cells * 2**levels` leaves (`group_lists`)."""

    tris: np.ndarray  # reordered triangle ids
    bounds: np.ndarray  # (pairs, leaves + 1) absolute leaf boundaries in `tris`
    levels: int
    cells: int


class TermTables(NamedTuple):
    """The cumulative term probabilities, each term's coefficients of 1, V_A, V_B, V_A V_B, and the groups it
    tests (MODE_*): per pair (the adaptive mixture's choices) or one row for all (a fixed decomposition)."""

    cdf: np.ndarray  # (pairs or 1, 3)
    coef: np.ndarray  # (pairs or 1, 3, 4)
    mode: np.ndarray  # (pairs or 1, 3) int8
    per_pair: bool


@njit(cache=True, error_model="numpy")
def _leaf_visible(cand, o, d, rs, tmax, tris, lo, hi, tests):
    """Binary visibility against one leaf group; adds its triangle tests and culled candidates to `tests`."""
    blocked, n_tri, n_cull = first_blocker(cand.triangles, cand.orientation, cand.fnormal, o, d, rs, tmax, tris, lo,
                                           hi)
    tests[0] += n_tri
    tests[1] += n_cull
    return 0.0 if blocked else 1.0


@njit(cache=True, error_model="numpy")
def _estimate(cand, o, d, rs, tmax, groups, pr, tp, g0, g1, depth, terms, key, dim, tests, chosen):
    """Unbiased estimate of the visibility of leaves g0..g1-1 of pair pr (term tables row tp), a subtree of the
    given depth."""
    bounds = groups.bounds
    if depth == 0:
        return _leaf_visible(cand, o, d, rs, tmax, groups.tris, bounds[pr, g0], bounds[pr, g1], tests)
    mid = (g0 + g1) // 2
    u = uniform(key, dim[0])
    dim[0] += 1
    t = 0
    while t < 2 and u >= terms.cdf[tp, t]:
        t += 1
    if chosen[0] < 0:
        chosen[0] = t
    m = terms.mode[tp, t]
    va, vb = 0.0, 0.0
    if m == MODE_A or m == MODE_AB_BLOCKED or m == MODE_BOTH or m == MODE_EXACT:
        va = _estimate(cand, o, d, rs, tmax, groups, pr, tp, g0, mid, depth - 1, terms, key, dim, tests, chosen)
    need_b = m == MODE_B or m == MODE_BOTH
    if m == MODE_AB_BLOCKED:
        need_b = not (depth == 1 and va == 1.0)  # A visible: the complement product is 0 whatever B is
    if m == MODE_EXACT:
        need_b = not (depth == 1 and va == 0.0)  # A blocks: visibility is 0 whatever B is
    if need_b:
        vb = _estimate(cand, o, d, rs, tmax, groups, pr, tp, mid, g1, depth - 1, terms, key, dim, tests, chosen)
    coef = terms.coef
    return coef[tp, t, 0] + coef[tp, t, 1] * va + coef[tp, t, 2] * vb + coef[tp, t, 3] * va * vb


@njit(cache=True, error_model="numpy")
def estimate_cells(cand, groups, terms, pr, o, d, rs, tmax, key, tests, dim, chosen):
    """Probabilistic visibility of one segment (origin o, direction d, `ray_setup` rs, rng key) over pair pr's
    grouped candidates: the product over cells of each cell's recursive estimate. Sets tests[0:2] to its triangle
    tests and culled candidates and chosen[0] to the first cell's top-level term (-1 if none); `dim` is
    scratch."""
    tp = pr if terms.per_pair else 0
    tests[0], tests[1], dim[0], chosen[0] = 0, 0, 0, -1
    per_cell = 1 << groups.levels
    v = 1.0
    for c in range(groups.cells):
        v *= _estimate(cand, o, d, rs, tmax, groups, pr, tp, c * per_cell, (c + 1) * per_cell, groups.levels, terms,
                       key, dim, tests, chosen)
    return v


@njit(cache=True, parallel=True, error_model="numpy")
def evaluate_segments(cand, org, dirs, tmax, pair, keys, groups, terms):
    """`estimate_cells` of each segment (`CandidateGeometry`, `GroupedLists`, `TermTables`). Returns values,
    triangle tests, culled candidates and the top-level term chosen (first cell)."""
    n = org.shape[0]
    value = np.empty(n)
    n_tri = np.zeros(n, np.int32)
    n_cull = np.zeros(n, np.int32)
    term = np.full(n, -1, np.int8)
    for chunk in prange((n + CHUNK - 1) // CHUNK):
        tests = np.zeros(2, np.int64)
        dim = np.zeros(1, np.int64)
        chosen = np.empty(1, np.int64)
        for s in range(chunk * CHUNK, min(n, (chunk + 1) * CHUNK)):
            o = (org[s, 0], org[s, 1], org[s, 2])
            d = (dirs[s, 0], dirs[s, 1], dirs[s, 2])
            value[s] = estimate_cells(cand, groups, terms, pair[s], o, d, ray_setup(d[0], d[1], d[2]), tmax[s],
                                      keys[s], tests, dim, chosen)
            n_tri[s], n_cull[s], term[s] = tests[0], tests[1], chosen[0]
    return value, n_tri, n_cull, term


@njit(cache=True, parallel=True, error_model="numpy")
def configuration_counts(nbr, nrm, photons, tris, bounds, n_rep, normal_cos):
    """Per pair, how many agreeing neighbour photons (`PhotonArrays`) saw each configuration (V_A, V_B) of its
    top-level split (leaves of the first half are A): a light photon sees (1, 1), a shadow photon is blocked by
    A or B when one of its recorded blockers lies in that group."""
    pn, nb, start, ray_tris = photons.normal, photons.n_blockers, photons.start, photons.ray_tris
    n_pairs = bounds.shape[0]
    half = (bounds.shape[1] - 1) // 2
    out = np.zeros((n_pairs, 4))
    for pr in prange(n_pairs):
        lo, mid, hi = bounds[pr, 0], bounds[pr, half], bounds[pr, bounds.shape[1] - 1]
        if hi == lo:
            continue
        i = pr % n_rep
        a_sorted = np.sort(tris[lo:mid])
        b_sorted = np.sort(tris[mid:hi])
        for k in range(nbr.shape[1]):
            j = nbr[i, k]
            if j < 0 or pn[j, 0] * nrm[i, 0] + pn[j, 1] * nrm[i, 1] + pn[j, 2] * nrm[i, 2] < normal_cos:
                continue
            va, vb = 1, 1
            for h in range(nb[j]):
                b = ray_tris[start[j] + h]
                p = np.searchsorted(a_sorted, b)
                if p < a_sorted.shape[0] and a_sorted[p] == b:
                    va = 0
                p = np.searchsorted(b_sorted, b)
                if p < b_sorted.shape[0] and b_sorted[p] == b:
                    vb = 0
            out[pr, 2 * va + vb] += 1.0
    return out
