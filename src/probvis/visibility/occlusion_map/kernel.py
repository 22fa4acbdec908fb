"""The occlusion map's render kernel: its estimators' own render path.

Per camera sample, the emitters its cases leave to be sampled get their segments (`shading.point_samples`);
then, per emitter, the pair's segments are evaluated together:

- unknown points, and penumbra points with `penumbra=bvh`, against the scene's BVH in packets;
- penumbra points with lists: the segments that need the whole list (the occlusion map's own test, verified
  segments, a pair the adaptive mixture evaluates exactly) stream it together, most often recorded blockers
  first, gathered into contiguous memory a chunk at a time, each leaving at its first blocker; the others draw a
  term of the decomposition, and the segments that need group A stream A, then those that need B stream B
  (`accel.stream_blockers`);
- verified segments (lit, shadowed, and penumbra ones whose list says visible) against the scene's BVH in
  packets, their correction terms added; a penumbra segment verified with q = 1, whose value V_list + (V -
  V_list) / q is V itself, is traced alone, its list untested.

Values, tests and random draws are those of the staged path (`OcclusionMapVisibility.evaluate`) bit for bit,
so both render the same image; only the traffic between them differs. The kernel also returns the estimator's
counters (named slots below) and its cycles per phase.
"""
from typing import NamedTuple

import numpy as np
from numba import njit

from ...accel import SHADOW_PACKET, buffered_blocker, occluded_packet, packet_work, ray_setup, root_record
from ...cases import CASE_LIT, CASE_MASK, CASE_PENUMBRA, CASE_SHADOWED, CASE_UNKNOWN, CASE_VERIFIED
from ...cycles import cycles
from ...parallel import over_lanes
from ...rng import mix64, uniform
from ...shading import (CAM_NODE, CAM_TRI, NEGATIVE, SH_NODE, SH_TRI, SHADOW_EPSILON, point_samples,
                        shaded_arrays)
from ..probabilistic.decomposition import MODE_A, MODE_AB_BLOCKED, MODE_B, MODE_BOTH, MODE_EXACT
from ..probabilistic.kernels import estimate_cells
from .verification import SEGMENT_DIM

PIXELS_PER_BLOCK = 4
PENUMBRA_BVH, PENUMBRA_LIST, PENUMBRA_TERMS = 0, 1, 2  # how penumbra segments are evaluated
# counters (summed over the batch)
N_COUNTERS = 14
(PENUMBRA_RAYS, UNKNOWN_RAYS, CULLED, TERM_0, TERM_1, TERM_2, EXACT_SELECTIONS, LIT_SEGMENTS, SHADOWED_SEGMENTS,
 PENUMBRA_SEGMENTS, LIT_VERIFIED, SHADOWED_VERIFIED, PENUMBRA_VERIFIED, PENUMBRA_MEASURED) = range(N_COUNTERS)
# per verified case (lit, shadowed, penumbra): Σ mismatch, Σ mismatch², Σ q
N_SUMS = 9
MISMATCH, MISMATCH2, Q_SUM = 0, 1, 2  # offsets within a case's three slots
LIT_SUMS, SHADOWED_SUMS, PENUMBRA_SUMS = 0, 3, 6
# phases whose cycles are counted
N_PHASES = 6
SAMPLING, TERM_CHOICE, CANDIDATE_TESTS, EXACT_TRACES, VERIFICATION_TRACES, FILM = range(N_PHASES)
PHASE_NAMES = ("sampling", "term_choice", "candidate_tests", "exact_traces", "verification_traces", "film")


class PairLists(NamedTuple):
    """A batch's look-ups as the kernel takes them: camera sample i's candidate list for emitter e is
    `tris[offsets[p]:offsets[p + 1]]` with pair p = e * n_rep + rep[i]."""

    rep: np.ndarray  # (m,) int64 look-up of each camera sample
    n_rep: int
    offsets: np.ndarray  # (emitters * n_rep + 1,) int64
    tris: np.ndarray  # int32, the most often recorded blockers first
    q: np.ndarray  # (m, emitters) verification probability of each pair's case (unused without `verify`)
    penumbra: int  # PENUMBRA_BVH, PENUMBRA_LIST or PENUMBRA_TERMS
    verify: bool


@njit(cache=True, error_model="numpy")
def _trace(bvh, root, org, dirs, tmin, tmax, idx, c, org2, dirs2, work, occ, n_node, n_tri, node_out, tri_out):
    """Any-hit tests of segments idx[:c] in packets of SHADOW_PACKET (gathered to the front of org2, dirs2); the
    occlusion into occ[:c], the tests added to node_out and tri_out of each segment."""
    for j in range(c):
        for d in range(3):
            org2[j, d] = org[idx[j], d]
            dirs2[j, d] = dirs[idx[j], d]
    for lo in range(0, c, SHADOW_PACKET):
        occluded_packet(bvh, root, org2, dirs2, tmin, tmax, lo, min(SHADOW_PACKET, c - lo), work, occ, n_node, n_tri)
    for j in range(c):
        node_out[idx[j]] += n_node[j]
        tri_out[idx[j]] += n_tri[j]


def shade_map(geom, es, bvh, batch, cand, lists, groups, terms, rows):
    """`ShadedBatch` arrays of a `ShadingBatch` with the occlusion map's estimators, and their counters (N_COUNTERS
    slots), verification sums (N_SUMS) and cycles per phase (N_PHASES). `cand` is the `CandidateGeometry`,
    `lists` the batch's `PairLists`, `groups` and `terms` the decomposition's `GroupedLists` and `TermTables`
    (with PENUMBRA_TERMS); `rows` is scratch for the gathered candidates, (threads, 2, longest list, 13)."""
    radiance, counts, n_seg = shaded_arrays(batch)
    n_blocks = (counts.shape[0] + PIXELS_PER_BLOCK - 1) // PIXELS_PER_BLOCK
    out = (radiance, counts, n_seg, np.zeros((n_blocks, N_COUNTERS), np.int64), np.zeros((n_blocks, N_SUMS)),
           np.zeros((n_blocks, N_PHASES)))
    root = root_record(bvh.root)

    def run(lane, lanes):
        _shade_blocks(geom, es, bvh, batch, (cand, lists, groups, terms, root, rows[lane]), lane, lanes, out,
                      _scratch(batch.shadow_rays), packet_work(bvh.stack_depth))

    over_lanes(run, n_blocks)
    return radiance, counts, n_seg, out[3].sum(axis=0), out[4].sum(axis=0), out[5].sum(axis=0)


def _scratch(n):
    """One thread's per-point arrays of `n` shadow-ray slots (`_shade_blocks` names them)."""
    f3, i64 = (lambda: np.empty((n, 3))), (lambda: np.empty(n, np.int64))
    return (f3(), f3(), f3(), f3(), f3(), np.empty(n, np.int32), np.empty(n, np.bool_), i64(), np.empty(n, np.uint64),
            np.empty(n), np.empty(n), np.empty(n, np.bool_), np.empty(n, np.int32), np.empty(n, np.int32), i64(), i64(),
            i64(), np.empty(n), np.empty(n, np.bool_), np.empty(n, np.bool_), i64(), i64(), np.empty((3, n), np.int64),
            np.empty(3, np.int64), i64(), i64(), i64(), i64(), i64(), np.empty(2, np.int64), np.empty(1, np.int64),
            np.empty(1, np.int64))


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def _shade_blocks(geom, es, bvh, batch, tables, lane, lanes, out, scratch, work):
    """Blocks lane, lane + lanes, ... of `shade_map`'s blocks of pixels, into `out` (its arrays, the
    counters, sums and cycles per block); `tables` are (cand, lists, groups, terms, the root record, this
    thread's rows). Serial and without Numba's allocator and reference counts, as `fused_exact`'s kernel."""
    cand, lists, groups, terms, root, scratch_rows = tables
    spp, n_emit = batch.spp, batch.cases.shape[1]
    radiance, counts, n_seg, counters, sums, phase = out
    (org, dirs, contrib, org2, dirs2, s_emit, active, slot, key, tmin, tmax, occ, node_j, tri_j, sh_node, sh_tri,
     n_cull, value, verified, alone, by_whole, by_general, by_term, n_term, exact_idx, lit_idx, shd_idx, ver_idx,
     alone_idx, tests, dim, chosen) = scratch
    n_pix = counts.shape[0]
    n_blocks = (n_pix + PIXELS_PER_BLOCK - 1) // PIXELS_PER_BLOCK
    general = groups.levels > 1 or groups.cells > 1
    list_rows, list_cull = scratch_rows[0, :, :9], scratch_rows[0, :, 9:]
    group_rows, group_cull = scratch_rows[1, :, :9], scratch_rows[1, :, 9:]
    for blk in range(lane, n_blocks, lanes):
        tmin[:] = 0.0
        tmax[:] = 1.0 - SHADOW_EPSILON
        n_term[:] = 0
        tests[:] = 0
        dim[:] = 0
        chosen[:] = 0
        for px in range(blk * PIXELS_PER_BLOCK, min(n_pix, (blk + 1) * PIXELS_PER_BLOCK)):
            for s in range(spp):
                i = px * spp + s
                t0 = cycles()
                counts[px, CAM_TRI] += batch.cam_tri[i]
                counts[px, CAM_NODE] += batch.cam_node[i]
                a0, a1, a2, m = point_samples(i, geom, es, batch, 0, org, dirs, contrib, s_emit, active, slot, True)
                t1 = cycles()
                phase[blk, SAMPLING] += t1 - t0
                n_exact = n_lit = n_shd = n_ver = n_alone = np.int64(0)  # not literals: one compile of _trace
                for k in range(m):
                    key[k] = mix64(batch.keys[i] + np.uint64(slot[k] + 1))
                    value[k] = 1.0
                    sh_node[k] = sh_tri[k] = n_cull[k] = 0
                    verified[k] = alone[k] = False
                    flagged = batch.cases[i, s_emit[k]]
                    case = flagged & CASE_MASK
                    if case == CASE_UNKNOWN:
                        counters[blk, UNKNOWN_RAYS] += 1
                        exact_idx[n_exact] = k
                        n_exact += 1
                    elif case == CASE_PENUMBRA:
                        counters[blk, PENUMBRA_RAYS] += 1
                        if lists.penumbra == PENUMBRA_BVH:
                            exact_idx[n_exact] = k
                            n_exact += 1
                    elif flagged == CASE_LIT | CASE_VERIFIED:
                        lit_idx[n_lit] = k
                        n_lit += 1
                    elif flagged == CASE_SHADOWED | CASE_VERIFIED:
                        shd_idx[n_shd] = k
                        n_shd += 1
                # penumbra segments on lists, emitter by emitter: the pair's segments together
                for e in range(n_emit if lists.penumbra != PENUMBRA_BVH else 0):
                    if batch.cases[i, e] & CASE_MASK != CASE_PENUMBRA:
                        continue
                    t2 = cycles()
                    pair = e * lists.n_rep + lists.rep[i]
                    lo, hi = lists.offsets[pair], lists.offsets[pair + 1]
                    tp = pair if terms.per_pair else 0
                    q = lists.q[i, e] if lists.verify else 0.0  # without verification q is a (1, 1) stand-in
                    whole = lists.penumbra == PENUMBRA_LIST or terms.mode[tp, 0] == MODE_EXACT
                    c0, c1 = terms.cdf[tp, 0], terms.cdf[tp, 1]
                    n_whole = n_general = 0
                    n_term[0] = n_term[1] = n_term[2] = 0
                    for k in range(m):  # each segment's verification draw, then its term: segments sorted by what they test
                        if s_emit[k] != e:
                            continue
                        counters[blk, PENUMBRA_SEGMENTS] += 1
                        verified[k] = lists.verify and uniform(key[k], SEGMENT_DIM) < q
                        alone[k] = verified[k] and q >= 1.0
                        if alone[k]:  # its value is V: the trace alone, no list
                            alone_idx[n_alone] = k
                            n_alone += 1
                        elif whole or verified[k]:
                            by_whole[n_whole] = k
                            n_whole += 1
                        elif general:
                            by_general[n_general] = k
                            n_general += 1
                        else:  # the first term whose cumulative probability exceeds u (branch-free: cdf is sorted)
                            u = uniform(key[k], 0)
                            t = np.int64(u >= c0) + np.int64(u >= c1)
                            by_term[t, n_term[t]] = k
                            n_term[t] += 1
                    if whole:
                        counters[blk, EXACT_SELECTIONS] += n_whole * (lists.penumbra == PENUMBRA_TERMS)
                    for t in range(3):
                        counters[blk, TERM_0 + t] += n_term[t]
                    t3 = cycles()
                    phase[blk, TERM_CHOICE] += t3 - t2
                    if n_whole + n_general + n_term[0] + n_term[1] + n_term[2] == 0:
                        continue
                    # the candidates are gathered as needed into rows shared by the pair's segments (one origin)
                    first = m
                    for k in range(m):
                        if s_emit[k] == e:
                            first = k
                            break
                    ox, oy, oz = org[first, 0], org[first, 1], org[first, 2]
                    have_l = have_a = have_b = 0
                    ga = gb = gc = 0  # the decomposition's groups, if any (NO_GROUPS has one row)
                    if lists.penumbra == PENUMBRA_TERMS:
                        ga, gb, gc = groups.bounds[pair, 0], groups.bounds[pair, 1], groups.bounds[pair, -1]
                    for j in range(n_whole):  # the whole list, most often recorded blockers first
                        k = by_whole[j]
                        d = (dirs[k, 0], dirs[k, 1], dirs[k, 2])
                        hit, n_t, n_c, have_l = buffered_blocker(cand, lists.tris, lo, hi, list_rows, list_cull, 0,
                                                                 have_l, ox, oy, oz, (org[k, 0], org[k, 1], org[k, 2]),
                                                                 d, ray_setup(d[0], d[1], d[2]), tmax[k])
                        sh_tri[k] += n_t
                        n_cull[k] += n_c
                        value[k] = 0.0 if hit else 1.0
                    for j in range(n_general):  # recursive levels or cells: the recursive estimate
                        k = by_general[j]
                        d = (dirs[k, 0], dirs[k, 1], dirs[k, 2])
                        value[k] = estimate_cells(cand, groups, terms, pair, (org[k, 0], org[k, 1], org[k, 2]), d,
                                                  ray_setup(d[0], d[1], d[2]), tmax[k], key[k], tests, dim, chosen)
                        sh_tri[k] += tests[0]
                        n_cull[k] += tests[1]
                        if chosen[0] >= 0:
                            counters[blk, TERM_0 + chosen[0]] += 1
                    for t in range(3):  # term by term: group A where the term needs it, then B given V_A
                        md = terms.mode[tp, t]
                        need_a = md == MODE_A or md == MODE_AB_BLOCKED or md == MODE_BOTH or md == MODE_EXACT
                        for j in range(n_term[t]):
                            k = by_term[t, j]
                            o = (org[k, 0], org[k, 1], org[k, 2])
                            d = (dirs[k, 0], dirs[k, 1], dirs[k, 2])
                            shear = ray_setup(d[0], d[1], d[2])
                            va = vb = 0.0
                            if need_a:
                                hit, n_t, n_c, have_a = buffered_blocker(cand, groups.tris, ga, gb, group_rows,
                                                                         group_cull, 0, have_a, ox, oy, oz, o, d,
                                                                         shear, tmax[k])
                                sh_tri[k] += n_t
                                n_cull[k] += n_c
                                va = 0.0 if hit else 1.0
                            if md == MODE_B or md == MODE_BOTH or (md == MODE_AB_BLOCKED and va == 0.0) or (
                                    md == MODE_EXACT and va == 1.0):
                                hit, n_t, n_c, have_b = buffered_blocker(cand, groups.tris, gb, gc, group_rows,
                                                                         group_cull, gb - ga, have_b, ox, oy, oz, o,
                                                                         d, shear, tmax[k])
                                sh_tri[k] += n_t
                                n_cull[k] += n_c
                                vb = 0.0 if hit else 1.0
                            value[k] = _term_value(terms, tp, t, va, vb)
                    phase[blk, CANDIDATE_TESTS] += cycles() - t3
                for k in range(m):  # verified penumbra segments whose list says visible are traced, in slot order
                    if verified[k] and not alone[k] and value[k] == 1.0:
                        ver_idx[n_ver] = k
                        n_ver += 1
                t4 = cycles()
                _trace(bvh, root, org, dirs, tmin, tmax, exact_idx, n_exact, org2, dirs2, work, occ, node_j, tri_j,
                       sh_node, sh_tri)
                for j in range(n_exact):
                    value[exact_idx[j]] = 1.0 - np.float64(occ[j])
                t5 = cycles()
                phase[blk, EXACT_TRACES] += t5 - t4
                if lists.verify:
                    _verify(bvh, root, org, dirs, tmin, tmax, lit_idx, n_lit, 1.0, lists.q[i], s_emit, org2, dirs2,
                            work, occ, node_j, tri_j, sh_node, sh_tri, value, sums[blk], np.int64(LIT_SUMS))
                    counters[blk, LIT_SEGMENTS] += n_lit
                    counters[blk, LIT_VERIFIED] += n_lit
                    _verify(bvh, root, org, dirs, tmin, tmax, shd_idx, n_shd, 0.0, lists.q[i], s_emit, org2, dirs2,
                            work, occ, node_j, tri_j, sh_node, sh_tri, value, sums[blk], np.int64(SHADOWED_SUMS))
                    counters[blk, SHADOWED_SEGMENTS] += n_shd
                    counters[blk, SHADOWED_VERIFIED] += n_shd
                    for k in range(m):
                        if verified[k] and batch.cases[i, s_emit[k]] & CASE_MASK == CASE_PENUMBRA:
                            counters[blk, PENUMBRA_VERIFIED] += 1
                            if not alone[k]:
                                counters[blk, PENUMBRA_MEASURED] += 1
                            sums[blk, PENUMBRA_SUMS + Q_SUM] += lists.q[i, s_emit[k]]
                    _trace(bvh, root, org, dirs, tmin, tmax, alone_idx, n_alone, org2, dirs2, work, occ, node_j,
                           tri_j, sh_node, sh_tri)
                    for j in range(n_alone):
                        value[alone_idx[j]] = 1.0 - np.float64(occ[j])
                    _verify(bvh, root, org, dirs, tmin, tmax, ver_idx, n_ver, 1.0, lists.q[i], s_emit, org2, dirs2,
                            work, occ, node_j, tri_j, sh_node, sh_tri, value, sums[blk], np.int64(PENUMBRA_SUMS))
                t6 = cycles()
                phase[blk, VERIFICATION_TRACES] += t6 - t5
                l0, l1, l2 = batch.emitted[i, 0] + a0, batch.emitted[i, 1] + a1, batch.emitted[i, 2] + a2
                for k in range(m):
                    v = value[k]
                    l0 += contrib[k, 0] * v
                    l1 += contrib[k, 1] * v
                    l2 += contrib[k, 2] * v
                    counts[px, SH_TRI] += sh_tri[k]
                    counts[px, SH_NODE] += sh_node[k]
                    counts[px, NEGATIVE] += v < 0.0
                    counters[blk, CULLED] += n_cull[k]
                n_seg[px] += m
                radiance[i, 0], radiance[i, 1], radiance[i, 2] = l0, l1, l2
                phase[blk, FILM] += cycles() - t6


@njit(cache=True, error_model="numpy", inline="always")
def _term_value(terms, tp, t, va, vb):
    """The chosen term's estimate of V_A V_B: c0 + c1 V_A + c2 V_B + c3 V_A V_B."""
    return terms.coef[tp, t, 0] + terms.coef[tp, t, 1] * va + terms.coef[tp, t, 2] * vb + terms.coef[tp, t, 3] * va * vb


@njit(cache=True, error_model="numpy")
def _verify(bvh, root, org, dirs, tmin, tmax, idx, c, approx, q, s_emit, org2, dirs2, work, occ, node_j, tri_j,
            sh_node, sh_tri, value, sums, base):
    """Trace the verified segments idx[:c] whose shortcut said `approx` and turn their values into
    `approx`'s correction: value + (V - approx) / q (for a lit pair's segments, whose value is 1, the sampled
    deficit (V - 1) / q; for a shadowed pair's, V / q); the mismatch V - approx summed into sums[base:]."""
    _trace(bvh, root, org, dirs, tmin, tmax, idx, c, org2, dirs2, work, occ, node_j, tri_j, sh_node, sh_tri)
    for j in range(c):
        k = idx[j]
        qk = q[s_emit[k]]
        mismatch = (1.0 - np.float64(occ[j])) - approx
        value[k] = mismatch / qk if approx == 0.0 or base == LIT_SUMS else value[k] + mismatch / qk
        sums[base + MISMATCH] += mismatch
        sums[base + MISMATCH2] += mismatch * mismatch
        if base != PENUMBRA_SUMS:
            sums[base + Q_SUM] += qk
