"""Proxy visibility's fused kernel: per shading point, emitter sampling, the proxy test of its segments, the
exact test of the chosen ones and the film, while the segments are in cache (the shape of `fused_exact`, with
a second BVH and the control variate). It also returns what `ProxyVisibility` measures: per emitter the sums
behind δ, and the tests split between proxy and scene geometry."""
import math

import numpy as np
from numba import njit, prange

from ..accel import MAX_PACKET, occluded_packet, packet_work, root_record
from ..emitters import point_samples
from ..film import CAM_NODE, CAM_TRI, N_COUNTS, NEGATIVE, SH_NODE, SH_TRI, add_sample, pixel_mean
from ..parallel import spread
from ..rng import mix64, uniform
from ..segments import SHADOW_EPSILON

PIXELS_PER_BLOCK = 4
CORRECTION_DIM = 1 << 21  # rng dimension of a segment's Bernoulli draw, apart from other estimators' draws


@njit(cache=True, parallel=True, error_model="numpy")
def shade_proxy(geom, es, bvh, proxy, prim, pos, nrm, mat, albedo, cases, keys, emitted, cam_node, cam_tri, spp,
                n_shadow, n_pix, q, exact_only, clearance):
    """The film of a batch of whole pixels (as `fused_exact.shade_exact`) with V_P + B (V - V_P) / q per segment,
    B ~ Bernoulli(q[emitter]) (V alone for `exact_only` emitters); the proxy test ignores the first `clearance`
    of each segment. Also returns per emitter the sums (count, Σ ((V - V_P) w)², Σ w V, Σ (w V)²) over segments
    tested both ways (w: luminance of the unoccluded contribution) and the node and triangle tests against the
    proxies and the scene."""
    root_s, root_p = root_record(bvh.root), root_record(proxy.root)
    n_emit = q.shape[0]
    img = np.zeros((n_pix, 3))
    m2 = np.zeros((n_pix, 3))
    counts = np.zeros((n_pix, N_COUNTS), np.int64)
    n_seg = np.zeros(n_pix, np.int64)
    n_blocks = (n_pix + PIXELS_PER_BLOCK - 1) // PIXELS_PER_BLOCK
    sums = np.zeros((n_blocks, n_emit, 4))
    tests = np.zeros((n_blocks, 4), np.int64)  # proxy node, proxy triangle, scene node, scene triangle
    for it in prange(n_blocks):
        blk = spread(it, n_blocks)
        org, dirs, contrib = np.empty((n_shadow, 3)), np.empty((n_shadow, 3)), np.empty((n_shadow, 3))
        org2, dirs2 = np.empty((n_shadow, 3)), np.empty((n_shadow, 3))
        s_emit = np.empty(n_shadow, np.int32)
        active = np.empty(n_shadow, np.bool_)
        tmin = np.empty(n_shadow)
        zero = np.zeros(n_shadow)
        tmax = np.full(n_shadow, 1.0 - SHADOW_EPSILON)
        occ, occ2 = np.empty(n_shadow, np.bool_), np.empty(n_shadow, np.bool_)
        p_node, p_tri = np.empty(n_shadow, np.int32), np.empty(n_shadow, np.int32)
        s_node, s_tri = np.empty(n_shadow, np.int32), np.empty(n_shadow, np.int32)
        chosen = np.empty(n_shadow, np.int64)
        value = np.empty(n_shadow)
        work = packet_work(max(bvh.stack_depth, proxy.stack_depth))
        for px in range(blk * PIXELS_PER_BLOCK, min(n_pix, (blk + 1) * PIXELS_PER_BLOCK)):
            for s in range(spp):
                i = px * spp + s
                counts[px, CAM_TRI] += cam_tri[i]
                counts[px, CAM_NODE] += cam_node[i]
                a0, a1, a2, m = point_samples(i, geom, es, prim, pos, nrm, mat, albedo, cases, keys, n_shadow, 0,
                                              org, dirs, contrib, s_emit, active, True)
                for k in range(m):
                    tmin[k] = clearance / math.sqrt(dirs[k, 0] ** 2 + dirs[k, 1] ** 2 + dirs[k, 2] ** 2)
                for lo in range(0, m, MAX_PACKET):
                    occluded_packet(proxy, root_p, org, dirs, tmin, tmax, lo, min(MAX_PACKET, m - lo), work, occ,
                                    p_node, p_tri)
                c = 0
                for k in range(m):
                    e = s_emit[k]
                    value[k] = 0.0 if exact_only[e] else 1.0 - np.float64(occ[k])
                    if exact_only[e] or uniform(mix64(keys[i] + np.uint64(k + 1)), CORRECTION_DIM) < q[e]:
                        chosen[c] = k
                        for d in range(3):
                            org2[c, d] = org[k, d]
                            dirs2[c, d] = dirs[k, d]
                        c += 1
                for lo in range(0, c, MAX_PACKET):
                    occluded_packet(bvh, root_s, org2, dirs2, zero, tmax, lo, min(MAX_PACKET, c - lo), work, occ2,
                                    s_node, s_tri)
                for j in range(c):
                    k = chosen[j]
                    e = s_emit[k]
                    v = 1.0 - np.float64(occ2[j])
                    counts[px, SH_NODE] += s_node[j]
                    counts[px, SH_TRI] += s_tri[j]
                    tests[blk, 2] += s_node[j]
                    tests[blk, 3] += s_tri[j]
                    if exact_only[e]:
                        value[k] = v
                        continue
                    w = 0.212671 * contrib[k, 0] + 0.715160 * contrib[k, 1] + 0.072169 * contrib[k, 2]
                    sums[blk, e, 0] += 1.0
                    sums[blk, e, 1] += ((v - value[k]) * w) ** 2
                    sums[blk, e, 2] += w * v
                    sums[blk, e, 3] += (w * v) ** 2
                    value[k] += (v - value[k]) / q[e]
                l0, l1, l2 = emitted[i, 0] + a0, emitted[i, 1] + a1, emitted[i, 2] + a2
                for k in range(m):
                    l0 += contrib[k, 0] * value[k]
                    l1 += contrib[k, 1] * value[k]
                    l2 += contrib[k, 2] * value[k]
                    counts[px, SH_NODE] += p_node[k]
                    counts[px, SH_TRI] += p_tri[k]
                    counts[px, NEGATIVE] += value[k] < 0.0
                    tests[blk, 0] += p_node[k]
                    tests[blk, 1] += p_tri[k]
                n_seg[px] += m
                add_sample(img, m2, px, l0, l1, l2)
            pixel_mean(img, m2, px, spp)
    return img, m2, counts, n_seg, sums.sum(axis=0), tests.sum(axis=0)
