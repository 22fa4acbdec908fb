"""The fused render path of exact visibility: emitter sampling, any-hit packet traversal against the scene's BVH
and each camera sample's radiance, shading point by shading point, so a point's segments are made, traced and
summed while they are in cache, with no batch-sized slot or segment arrays. The arithmetic and the packets are
those of the staged path, so image and counts are identical (tested).

The kernel is serial and runs without Numba's allocator and reference counts (`_nrt=False`): `over_lanes`
runs it on the thread budget, each thread with scratch arrays of its own. Compiled as a `prange` loop it took
three times as long to compile; compiled serial with reference counts it ran three times slower, since every
read of a record's array inside the loop was an atomic increment and decrement (the parallel loop's passes
hoist those reads out of the loop)."""
import numpy as np
from numba import njit

from .accel import SHADOW_PACKET, occluded_packet, packet_work, root_record
from .parallel import over_lanes
from .shading import CAM_NODE, CAM_TRI, SH_NODE, SH_TRI, SHADOW_EPSILON, point_samples, shaded_arrays

PIXELS_PER_BLOCK = 4  # pixels per parallel work item


def shade_exact(geom, es, bvh, batch):
    """`ShadedBatch` arrays of a `ShadingBatch` with exact visibility: each camera sample's radiance, per-pixel
    counts and segments. `geom` is the `SceneArrays`, `es` the `EmitterArrays`, `bvh` the `BVHArrays`."""
    out = shaded_arrays(batch)
    root2 = root_record(bvh.root)
    n_blocks = (out[1].shape[0] + PIXELS_PER_BLOCK - 1) // PIXELS_PER_BLOCK

    def run(lane, lanes):
        _shade_blocks(geom, es, bvh, batch, root2, lane, lanes, out, _scratch(batch.shadow_rays),
                      packet_work(bvh.stack_depth))

    over_lanes(run, n_blocks)
    return out


def _scratch(n):
    """One thread's per-point arrays of `n` shadow-ray slots: origin, direction, contribution, emitter, sample,
    active, tmin, tmax, occluded, node and triangle tests."""
    return (np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3)), np.empty(n, np.int32), np.empty(n, np.int64),
            np.empty(n, np.bool_), np.empty(n), np.empty(n), np.empty(n, np.bool_), np.empty(n, np.int32),
            np.empty(n, np.int32))


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def _shade_blocks(geom, es, bvh, batch, root2, lane, lanes, out, scratch, work):
    """Blocks lane, lane + lanes, ... of `shade_exact`'s blocks of pixels, into `out` (its arrays)."""
    spp = batch.spp
    radiance, counts, n_seg = out
    org, dirs, contrib, s_emit, sample, active, tmin, tmax, occ, sh_node, sh_tri = scratch
    n_pix = counts.shape[0]
    n_blocks = (n_pix + PIXELS_PER_BLOCK - 1) // PIXELS_PER_BLOCK
    for blk in range(lane, n_blocks, lanes):
        tmin[:] = 0.0
        tmax[:] = 1.0 - SHADOW_EPSILON
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
