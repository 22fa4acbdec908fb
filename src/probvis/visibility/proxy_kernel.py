"""Proxy visibility's fused kernel: per shading point, emitter sampling, the shell tests that decide segments
exactly, the proxy test of the others, the exact test of the chosen ones and each camera sample's radiance,
while the segments are in cache (the shape of the integrator's fused exact kernel, with more BVHs and the
control variate). Exact visibility with shells renders through it too, every emitter exact-only. It also
returns what `ProxyVisibility` measures: per pixel and emitter the sums behind δ, and the tests split between
proxy, scene and shell geometry.
"""
import math
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from ..accel import SHADOW_PACKET, occluded_packet, packet_work, root_record
from ..color import luminance
from ..rng import mix64, uniform
from ..shading import CAM_NODE, CAM_TRI, NEGATIVE, SH_NODE, SH_TRI, SHADOW_EPSILON, point_samples, shaded_arrays
from ..shells import FREE, SOLID, segment_class
from ..transmittance import optical_depth

PIXELS_PER_BLOCK = 4
CORRECTION_DIM = 1 << 21  # rng dimension of a segment's Bernoulli draw, apart from other estimators' draws
# tests by geometry (summed over the batch): node and triangle tests of proxy and scene geometry (the rest of
# the scene's included), voxels walked in the shells' grid and in the extinction grid
N_TESTS = 6
PROXY_NODE, PROXY_TRI, SCENE_NODE, SCENE_TRI, SHELL_VOXEL, VOLUME_VOXEL = range(N_TESTS)
# per pixel and emitter, over segments decided by the shells (p = 1) and segments tested both ways (p = the
# segment's `segment_q`):
# segments tested both ways, Σ ((V - V_P) w)² / q, Σ w V / p, Σ (w V)² / p, Σ 1 / p (w: the luminance of the
# segment's unoccluded contribution); over the segments tested both ways, Σ w / q and Σ (V - V_P)² w / q
N_SUMS = 7
SUM_BOTH, SUM_MISMATCH, SUM_WV, SUM_WV2, SUM_INV_P, SUM_W, SUM_MISMATCH_W = range(N_SUMS)
WEIGHT_FLOOR = 0.1  # a segment's q is at least this share of its pixel's q


class Correction(NamedTuple):
    """Per pixel of the batch and emitter: the probability q of testing a segment exactly, and whether it is
    tested exactly alone (no proxy); per emitter the weight at which a segment takes q itself: a segment of
    weight w (`segment_q`) takes q w / weight, where weight > 0."""

    q: np.ndarray  # (n_pix, emitters)
    exact_only: np.ndarray  # (n_pix, emitters) bool
    weight: np.ndarray  # (emitters,)


@njit(cache=True, error_model="numpy", inline="always")
def segment_q(q, w, weight):
    """A segment's probability of the exact test: q, or where `weight` > 0 in proportion to the luminance w of
    its unoccluded contribution (the correction's variance is ((V - V_P) w)² / q, so the q that minimises
    variance x tests grows with w), at least WEIGHT_FLOOR q and at most 1."""
    if weight <= 0.0:
        return q
    return min(1.0, q * max(w / weight, WEIGHT_FLOOR))


def geometry_tests(tests):
    """`shade_proxy`'s tests (N_TESTS slots) as the stats report them."""
    return {"proxy": {"node": int(tests[PROXY_NODE]), "triangle": int(tests[PROXY_TRI]),
                      "voxel": int(tests[VOLUME_VOXEL])},
            "scene": {"node": int(tests[SCENE_NODE]), "triangle": int(tests[SCENE_TRI])},
            "shells": {"voxel": int(tests[SHELL_VOXEL])}}


@njit(cache=True, error_model="numpy")
def _gather(org, dirs, idx, c, org2, dirs2):
    """Copy segments idx[:c] to the front of org2 and dirs2 (the packets of a subset)."""
    for j in range(c):
        for d in range(3):
            org2[j, d] = org[idx[j], d]
            dirs2[j, d] = dirs[idx[j], d]


@njit(cache=True, error_model="numpy")
def _trace(bvh, root, org, dirs, tmin, tmax, c, work, occ, n_node, n_tri):
    """Any-hit tests of segments 0..c-1 in packets: the rest of the scene's, after the shells (not inlined:
    three inlined traversals take Numba minutes to compile)."""
    for lo in range(0, c, SHADOW_PACKET):
        occluded_packet(bvh, root, org, dirs, tmin, tmax, lo, min(SHADOW_PACKET, c - lo), work, occ, n_node, n_tri)


@njit(cache=True, parallel=True, error_model="numpy")
def shade_proxy(geom, es, bvh, batch, proxy, volume, clearance, shells, rest, plan, threads):
    """`ShadedBatch` arrays of a `ShadingBatch` (as the fused exact kernel's) with V_P + B (V - V_P) / q per
    segment, B ~ Bernoulli(q), q the segment's `segment_q` under `plan` (V alone where `plan.exact_only`, a
    `Correction`); V_P is
    the visibility against the `proxy` BVH, whose test ignores the first `clearance` of each segment, times the
    transmittance through the extinction grid `volume` of the volumetric proxies (see `probvis.transmittance`).

    With `shells.active` (`ShellArrays`, see `probvis.shells`), a segment whose walk through the grid enters a
    SOLID voxel is blocked, and one that visits only FREE voxels is tested against `rest` (the BVH of the scene
    without its heavy meshes) alone: both exactly, with no proxy test and no variance. The exact test of the
    others covers the scene only over the t range of their SURFACE voxels (where heavy meshes can be) and
    `rest` over the whole segment.

    Also returns the per pixel and emitter sums (N_SUMS slots) and the tests by geometry (N_TESTS slots)."""
    root_s, root_p, root_r = root_record(bvh.root), root_record(proxy.root), root_record(rest.root)
    depth = max(bvh.stack_depth, proxy.stack_depth, rest.stack_depth)
    q, exact_only, weight = plan.q, plan.exact_only, plan.weight
    spp, n_shadow = batch.spp, batch.shadow_rays
    radiance, counts, n_seg = shaded_arrays(batch)
    n_pix, n_emit = q.shape
    n_blocks = (n_pix + PIXELS_PER_BLOCK - 1) // PIXELS_PER_BLOCK
    sums = np.zeros((n_pix, n_emit, N_SUMS))
    tests = np.zeros((n_blocks, N_TESTS), np.int64)
    lanes = min(threads, n_blocks)
    for lane in prange(lanes):  # one lane of blocks per thread (see `parallel`)
        for blk in range(lane, n_blocks, lanes):
            org, dirs, contrib = np.empty((n_shadow, 3)), np.empty((n_shadow, 3)), np.empty((n_shadow, 3))
            org2, dirs2 = np.empty((n_shadow, 3)), np.empty((n_shadow, 3))
            s_emit, sample = np.empty(n_shadow, np.int32), np.empty(n_shadow, np.int64)
            active = np.empty(n_shadow, np.bool_)
            tmin = np.empty(n_shadow)
            zero = np.zeros(n_shadow)
            tmax = np.full(n_shadow, 1.0 - SHADOW_EPSILON)
            occ = np.empty(n_shadow, np.bool_)
            n_node, n_tri = np.empty(n_shadow, np.int32), np.empty(n_shadow, np.int32)
            idx, idx2 = np.empty(n_shadow, np.int64), np.empty(n_shadow, np.int64)
            org3, dirs3 = np.empty((n_shadow, 3)), np.empty((n_shadow, 3))
            t_lo, t_hi, t_end = np.empty(n_shadow), np.empty(n_shadow), np.empty(n_shadow)
            occ2 = np.empty(n_shadow, np.bool_)
            decided = np.empty(n_shadow, np.bool_)
            value, q_k = np.empty(n_shadow), np.empty(n_shadow)
            work = packet_work(depth)
            for px in range(blk * PIXELS_PER_BLOCK, min(n_pix, (blk + 1) * PIXELS_PER_BLOCK)):
                for s in range(spp):
                    i = px * spp + s
                    counts[px, CAM_TRI] += batch.cam_tri[i]
                    counts[px, CAM_NODE] += batch.cam_node[i]
                    a0, a1, a2, m = point_samples(i, geom, es, batch, 0, org, dirs, contrib, s_emit, active, sample,
                                                  True)
                    for k in range(m):
                        decided[k] = False
                        value[k] = 0.0
                        t_lo[k] = 0.0
                        t_hi[k] = tmax[k]
                    # walk the shells' grid; the segments it finds clear meet the rest of the scene only
                    if shells.active:
                        c = 0
                        for k in range(m):
                            state, steps, t_lo[k], t_hi[k] = segment_class(
                                shells.grid, shells.lo, shells.pitch, org[k, 0], org[k, 1], org[k, 2], dirs[k, 0],
                                dirs[k, 1], dirs[k, 2], tmax[k])
                            tests[blk, SHELL_VOXEL] += steps
                            if state == SOLID:
                                decided[k] = True
                            elif state == FREE:
                                idx[c] = k
                                c += 1
                        _gather(org, dirs, idx, c, org2, dirs2)
                        _trace(rest, root_r, org2, dirs2, zero, tmax, c, work, occ, n_node, n_tri)
                        for j in range(c):
                            k = idx[j]
                            decided[k] = True
                            value[k] = 1.0 - np.float64(occ[j])
                            tests[blk, SCENE_NODE] += n_node[j]
                            tests[blk, SCENE_TRI] += n_tri[j]
                            counts[px, SH_NODE] += n_node[j]
                            counts[px, SH_TRI] += n_tri[j]
                        for k in range(m):  # decided segments count in the variance with p = 1
                            e = s_emit[k]
                            if decided[k] and not exact_only[px, e]:
                                wv = value[k] * luminance(contrib[k, 0], contrib[k, 1], contrib[k, 2])
                                sums[px, e, SUM_WV] += wv
                                sums[px, e, SUM_WV2] += wv * wv
                                sums[px, e, SUM_INV_P] += 1.0
                    # the proxy test of the undecided segments of emitters that use proxies
                    c = 0
                    for k in range(m):
                        if not decided[k] and not exact_only[px, s_emit[k]]:
                            idx[c] = k
                            tmin[c] = clearance / math.sqrt(dirs[k, 0] ** 2 + dirs[k, 1] ** 2 + dirs[k, 2] ** 2)
                            c += 1
                    if c < m:
                        _gather(org, dirs, idx, c, org2, dirs2)
                    for lo in range(0, c, SHADOW_PACKET):  # inlined, as is the exact test below: the hot traversals
                        occluded_packet(proxy, root_p, org if c == m else org2, dirs if c == m else dirs2, tmin,
                                        tmax, lo, min(SHADOW_PACKET, c - lo), work, occ, n_node, n_tri)
                    for j in range(c):
                        k = idx[j]
                        value[k] = 0.0
                        if not occ[j]:
                            tau, steps = optical_depth(volume, org[k, 0], org[k, 1], org[k, 2], dirs[k, 0],
                                                       dirs[k, 1], dirs[k, 2], tmax[k])
                            value[k] = math.exp(-tau)
                            tests[blk, VOLUME_VOXEL] += steps
                        tests[blk, PROXY_NODE] += n_node[j]
                        tests[blk, PROXY_TRI] += n_tri[j]
                        counts[px, SH_NODE] += n_node[j]
                        counts[px, SH_TRI] += n_tri[j]
                    # the exact test of the undecided segments of exact-only emitters and a random fraction q of
                    # the rest
                    c = 0
                    for k in range(m):
                        e = s_emit[k]
                        if decided[k]:
                            continue
                        q_k[k] = 1.0
                        if not exact_only[px, e]:
                            q_k[k] = segment_q(q[px, e], luminance(contrib[k, 0], contrib[k, 1], contrib[k, 2]),
                                               weight[e])
                        draw = uniform(mix64(batch.keys[i] + np.uint64(k + 1)), CORRECTION_DIM)
                        if exact_only[px, e] or draw < q_k[k]:
                            idx[c] = k
                            tmin[c] = t_lo[k]
                            t_end[c] = t_hi[k]
                            c += 1
                    if c < m:
                        _gather(org, dirs, idx, c, org2, dirs2)
                    for lo in range(0, c, SHADOW_PACKET):  # with shells, only where heavy meshes can block
                        occluded_packet(bvh, root_s, org if c == m else org2, dirs if c == m else dirs2, tmin,
                                        t_end, lo, min(SHADOW_PACKET, c - lo), work, occ, n_node, n_tri)
                    for j in range(c):
                        counts[px, SH_NODE] += n_node[j]
                        counts[px, SH_TRI] += n_tri[j]
                        tests[blk, SCENE_NODE] += n_node[j]
                        tests[blk, SCENE_TRI] += n_tri[j]
                        occ2[j] = occ[j]
                    if shells.active:  # and the rest of the scene along the whole segment, where that found no blocker
                        f = 0
                        for j in range(c):
                            if not occ[j]:
                                idx2[f] = j
                                f += 1
                        _gather(org if c == m else org2, dirs if c == m else dirs2, idx2, f, org3, dirs3)
                        _trace(rest, root_r, org3, dirs3, zero, tmax, f, work, occ, n_node, n_tri)
                        for j in range(f):
                            occ2[idx2[j]] = occ[j]
                            counts[px, SH_NODE] += n_node[j]
                            counts[px, SH_TRI] += n_tri[j]
                            tests[blk, SCENE_NODE] += n_node[j]
                            tests[blk, SCENE_TRI] += n_tri[j]
                    for j in range(c):
                        k = idx[j]
                        e = s_emit[k]
                        v = 1.0 - np.float64(occ2[j])
                        if exact_only[px, e]:
                            value[k] = v
                            continue
                        w, p = luminance(contrib[k, 0], contrib[k, 1], contrib[k, 2]), q_k[k]
                        sums[px, e, SUM_BOTH] += 1.0
                        sums[px, e, SUM_MISMATCH] += ((v - value[k]) * w) ** 2 / p
                        sums[px, e, SUM_WV] += w * v / p
                        sums[px, e, SUM_WV2] += (w * v) ** 2 / p
                        sums[px, e, SUM_INV_P] += 1.0 / p
                        sums[px, e, SUM_W] += w / p
                        sums[px, e, SUM_MISMATCH_W] += (v - value[k]) ** 2 * w / p
                        value[k] += (v - value[k]) / p
                    l0, l1, l2 = batch.emitted[i, 0] + a0, batch.emitted[i, 1] + a1, batch.emitted[i, 2] + a2
                    for k in range(m):
                        l0 += contrib[k, 0] * value[k]
                        l1 += contrib[k, 1] * value[k]
                        l2 += contrib[k, 2] * value[k]
                        counts[px, NEGATIVE] += value[k] < 0.0
                    n_seg[px] += m
                    radiance[i, 0], radiance[i, 1], radiance[i, 2] = l0, l1, l2
    return radiance, counts, n_seg, sums, tests.sum(axis=0)
