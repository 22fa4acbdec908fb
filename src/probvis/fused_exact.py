"""Stages 3-5 fused for estimators that declare `fused_any_hit` (exact visibility): emitter sampling, any-hit
packet traversal against the scene's BVH and the film, pixel by pixel, so a shading point's segments are
made, traced and summed while they are in cache, with no batch-sized slot or segment arrays. The arithmetic
and the packets are those of the staged path, so image and counts are identical (tested)."""
import numpy as np
from numba import njit, prange

from .accel import SHADOW_PACKET, occluded_packet, packet_work, root_record
from .emitters import point_samples
from .film import CAM_NODE, CAM_TRI, N_COUNTS, SH_NODE, SH_TRI, add_sample, pixel_mean
from .parallel import spread
from .segments import SHADOW_EPSILON

PIXELS_PER_BLOCK = 4  # pixels per parallel work item


@njit(cache=True, parallel=True, error_model="numpy")
def shade_exact(geom, es, bvh, prim, pos, nrm, mat, albedo, cases, keys, emitted, cam_node, cam_tri, spp, n_shadow,
                n_pix):
    """The film of a batch of whole pixels with exact visibility: `film.accumulate`'s outputs and the number of
    shadow segments per pixel."""
    root2 = root_record(bvh.root)
    img = np.zeros((n_pix, 3))
    m2 = np.zeros((n_pix, 3))
    counts = np.zeros((n_pix, N_COUNTS), np.int64)
    n_seg = np.zeros(n_pix, np.int64)
    n_blocks = (n_pix + PIXELS_PER_BLOCK - 1) // PIXELS_PER_BLOCK
    for it in prange(n_blocks):
        blk = spread(it, n_blocks)
        org, dirs, contrib = np.empty((n_shadow, 3)), np.empty((n_shadow, 3)), np.empty((n_shadow, 3))
        s_emit = np.empty(n_shadow, np.int32)
        active = np.empty(n_shadow, np.bool_)
        tmin = np.zeros(n_shadow)
        tmax = np.full(n_shadow, 1.0 - SHADOW_EPSILON)
        occ = np.empty(n_shadow, np.bool_)
        sh_node = np.empty(n_shadow, np.int32)
        sh_tri = np.empty(n_shadow, np.int32)
        work = packet_work(bvh.stack_depth)
        for q in range(blk * PIXELS_PER_BLOCK, min(n_pix, (blk + 1) * PIXELS_PER_BLOCK)):
            for s in range(spp):
                i = q * spp + s
                counts[q, CAM_TRI] += cam_tri[i]
                counts[q, CAM_NODE] += cam_node[i]
                a0, a1, a2, m = point_samples(i, geom, es, prim, pos, nrm, mat, albedo, cases, keys, n_shadow, 0,
                                              org, dirs, contrib, s_emit, active, True)
                for lo in range(0, m, SHADOW_PACKET):
                    occluded_packet(bvh, root2, org, dirs, tmin, tmax, lo, min(SHADOW_PACKET, m - lo), work, occ,
                                    sh_node, sh_tri)
                l0, l1, l2 = emitted[i, 0] + a0, emitted[i, 1] + a1, emitted[i, 2] + a2
                for k in range(m):
                    v = 1.0 - np.float64(occ[k])
                    l0 += contrib[k, 0] * v
                    l1 += contrib[k, 1] * v
                    l2 += contrib[k, 2] * v
                    counts[q, SH_TRI] += sh_tri[k]
                    counts[q, SH_NODE] += sh_node[k]
                n_seg[q] += m
                add_sample(img, m2, q, l0, l1, l2)
            pixel_mean(img, m2, q, spp)
    return img, m2, counts, n_seg
