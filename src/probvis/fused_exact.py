"""The fused render path of exact visibility: emitter sampling, any-hit packet traversal against the scene's BVH
and each camera sample's radiance, shading point by shading point, so a point's segments are made, traced and
summed while they are in cache, with no batch-sized slot or segment arrays. The arithmetic and the packets are
those of the staged path, so image and counts are identical (tested)."""
import numpy as np
from numba import njit, prange

from .accel import SHADOW_PACKET, occluded_packet, packet_work, root_record
from .parallel import spread
from .shading import CAM_NODE, CAM_TRI, SH_NODE, SH_TRI, SHADOW_EPSILON, point_samples, shaded_arrays

PIXELS_PER_BLOCK = 4  # pixels per parallel work item


@njit(cache=True, parallel=True, error_model="numpy")
def shade_exact(geom, es, bvh, batch):
    """`ShadedBatch` arrays of a `ShadingBatch` with exact visibility: each camera sample's radiance, per-pixel
    counts and segments. `geom` is the `SceneArrays`, `es` the `EmitterArrays`, `bvh` the `BVHArrays`."""
    root2 = root_record(bvh.root)
    spp, n_shadow = batch.spp, batch.shadow_rays
    radiance, counts, n_seg = shaded_arrays(batch)
    n_pix = counts.shape[0]
    n_blocks = (n_pix + PIXELS_PER_BLOCK - 1) // PIXELS_PER_BLOCK
    for it in prange(n_blocks):
        blk = spread(it, n_blocks)
        org, dirs, contrib = np.empty((n_shadow, 3)), np.empty((n_shadow, 3)), np.empty((n_shadow, 3))
        s_emit, sample = np.empty(n_shadow, np.int32), np.empty(n_shadow, np.int64)
        active = np.empty(n_shadow, np.bool_)
        tmin = np.zeros(n_shadow)
        tmax = np.full(n_shadow, 1.0 - SHADOW_EPSILON)
        occ = np.empty(n_shadow, np.bool_)
        sh_node = np.empty(n_shadow, np.int32)
        sh_tri = np.empty(n_shadow, np.int32)
        work = packet_work(bvh.stack_depth)
        for px in range(blk * PIXELS_PER_BLOCK, min(n_pix, (blk + 1) * PIXELS_PER_BLOCK)):
            for s in range(spp):
                i = px * spp + s
                counts[px, CAM_TRI] += batch.cam_tri[i]
                counts[px, CAM_NODE] += batch.cam_node[i]
                a0, a1, a2, m = point_samples(i, geom, es, batch, 0, org, dirs, contrib, s_emit, active, sample, True)
                for lo in range(0, m, SHADOW_PACKET):
                    occluded_packet(bvh, root2, org, dirs, tmin, tmax, lo, min(SHADOW_PACKET, m - lo), work, occ,
                                    sh_node, sh_tri)
                l0, l1, l2 = batch.emitted[i, 0] + a0, batch.emitted[i, 1] + a1, batch.emitted[i, 2] + a2
                for k in range(m):
                    v = 1.0 - np.float64(occ[k])
                    l0 += contrib[k, 0] * v
                    l1 += contrib[k, 1] * v
                    l2 += contrib[k, 2] * v
                    counts[px, SH_TRI] += sh_tri[k]
                    counts[px, SH_NODE] += sh_node[k]
                n_seg[px] += m
                radiance[i, 0], radiance[i, 1], radiance[i, 2] = l0, l1, l2
    return radiance, counts, n_seg
