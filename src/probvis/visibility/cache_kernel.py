"""The cached estimators' own render kernel (`shade_cached`) and the cache's per-segment arithmetic it shares with
the staged interface: per shading point its segments as every path makes them (`shading.point_samples`), each
segment's voxel pair looked up in the cache, its coin drawn from the key the staged path gives the segment, the
drawn segments traced in packets and the samples' radiance — value for value what `CachedVisibility.evaluate`
returns on the staged path (tested)."""
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from ..accel import SHADOW_PACKET, occluded_packet, packet_work, root_record
from ..rng import mix64, uniform
from ..shading import CAM_NODE, CAM_TRI, NEGATIVE, SH_NODE, SH_TRI, SHADOW_EPSILON, point_samples, shaded_arrays

PIXELS_PER_BLOCK = 4  # pixels per parallel work item


class CacheArrays(NamedTuple):
    """What the kernels read of a `VisibilityCache`."""

    corner: np.ndarray  # (3,) the grid's lower corner
    pitch: float  # the voxels' side
    dims: np.ndarray  # (3,) int64 voxels per axis
    row: np.ndarray  # (voxels + 1,) int64: the pairs of shading-point voxel a are row[a]:row[a + 1]
    emitter_voxel: np.ndarray  # (k,) int64 the pairs' emitter-point voxels, sorted within each row
    visible: np.ndarray  # (k,) unoccluded pilot segments of each pair
    total: np.ndarray  # (k,) int64 pilot segments of each pair


class CachePlan(NamedTuple):
    """How an estimator turns a segment's cached share `mean` (over `total` pilot segments) into its control
    value c and its probability p of being traced: c = `control` × mean; p = `fixed` if positive, else mean
    (`RULE_SHARE`) or 2 sqrt(mean (1 − mean)) (`RULE_UNCERTAINTY`), at least `min_p`; p = 1 and c = 0 where the
    pilot saw the pair never."""

    control: float
    rule: int
    fixed: float
    min_p: float


RULE_SHARE, RULE_UNCERTAINTY = 0, 1


@njit(cache=True, error_model="numpy", inline="always")
def pair_key(cache, ox, oy, oz, dx, dy, dz):
    """The key (shading point's voxel) × voxels + (emitter point's voxel) of the segment o + t d, t in [0, 1];
    points outside the grid (an environment's far points) fall in its border voxels."""
    dims = cache.dims
    a = np.int64(0)
    b = np.int64(0)
    for c, o, d in ((0, ox, dx), (1, oy, dy), (2, oz, dz)):
        ia = min(dims[c] - 1, max(0, np.int64(np.floor((o - cache.corner[c]) / cache.pitch))))
        ib = min(dims[c] - 1, max(0, np.int64(np.floor((o + d - cache.corner[c]) / cache.pitch))))
        a = a * dims[c] + ia
        b = b * dims[c] + ib
    return a * (dims[0] * dims[1] * dims[2]) + b


@njit(cache=True, error_model="numpy", inline="always")
def segment_plan(cache, plan, ox, oy, oz, dx, dy, dz):
    """(c, p) of the segment o + t d from its voxel pair's pilot counts (see `CachePlan`)."""
    key = pair_key(cache, ox, oy, oz, dx, dy, dz)
    nv = cache.row.shape[0] - 1
    a, b = key // nv, key % nv
    lo, hi = cache.row[a], cache.row[a + 1]
    at = lo + np.searchsorted(cache.emitter_voxel[lo:hi], b)
    if at >= hi or cache.emitter_voxel[at] != b:
        return 0.0, 1.0
    mean = cache.visible[at] / cache.total[at]
    if plan.fixed > 0.0:
        p = plan.fixed
    elif plan.rule == RULE_SHARE:
        p = mean
    else:
        p = 2.0 * np.sqrt(mean * (1.0 - mean))
    return plan.control * mean, min(1.0, max(plan.min_p, p))


@njit(cache=True, parallel=True, error_model="numpy")
def segment_plans(cache, plan, origin, direction):
    """`segment_plan` of every segment: (c, p) arrays."""
    n = origin.shape[0]
    c = np.empty(n)
    p = np.empty(n)
    for i in prange(n):
        c[i], p[i] = segment_plan(cache, plan, origin[i, 0], origin[i, 1], origin[i, 2], direction[i, 0],
                                  direction[i, 1], direction[i, 2])
    return c, p


@njit(cache=True, parallel=True, error_model="numpy")
def pair_keys(cache, origin, direction):
    """`pair_key` of every segment."""
    n = origin.shape[0]
    out = np.empty(n, np.int64)
    for i in prange(n):
        out[i] = pair_key(cache, origin[i, 0], origin[i, 1], origin[i, 2], direction[i, 0], direction[i, 1],
                          direction[i, 2])
    return out


@njit(cache=True, parallel=True, error_model="numpy")
def shade_cached(geom, es, bvh, batch, cache, plan, threads):
    """`ShadedBatch` arrays of a `ShadingBatch` with the estimate c + B (V − c) / p per segment (c, p from
    `segment_plan`), and the segments traced per pixel. `geom` is the `SceneArrays`, `es` the `EmitterArrays`,
    `bvh` the `BVHArrays`, `cache` the `CacheArrays`, `plan` the `CachePlan`, `threads` the thread budget."""
    root2 = root_record(bvh.root)
    spp, n_shadow = batch.spp, batch.shadow_rays
    radiance, counts, n_seg = shaded_arrays(batch)
    n_pix = counts.shape[0]
    traced = np.zeros(n_pix)
    n_blocks = (n_pix + PIXELS_PER_BLOCK - 1) // PIXELS_PER_BLOCK
    lanes = min(threads, n_blocks)
    for lane in prange(lanes):  # one lane of blocks per thread (see `parallel`)
        for blk in range(lane, n_blocks, lanes):
            org, dirs, contrib = np.empty((n_shadow, 3)), np.empty((n_shadow, 3)), np.empty((n_shadow, 3))
            org2, dirs2 = np.empty((n_shadow, 3)), np.empty((n_shadow, 3))
            s_emit, sample = np.empty(n_shadow, np.int32), np.empty(n_shadow, np.int64)
            active = np.empty(n_shadow, np.bool_)
            value, prob, drawn = np.empty(n_shadow), np.empty(n_shadow), np.empty(n_shadow, np.int64)
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
                    a0, a1, a2, m = point_samples(i, geom, es, batch, 0, org, dirs, contrib, s_emit, active, sample,
                                                  True)
                    nd = 0
                    for k in range(m):
                        value[k], prob[k] = segment_plan(cache, plan, org[k, 0], org[k, 1], org[k, 2], dirs[k, 0],
                                                         dirs[k, 1], dirs[k, 2])
                        if uniform(mix64(batch.keys[i] + np.uint64(sample[k] + 1)), 0) < prob[k]:
                            for c in range(3):
                                org2[nd, c] = org[k, c]
                                dirs2[nd, c] = dirs[k, c]
                            drawn[nd] = k
                            nd += 1
                    for lo in range(0, nd, SHADOW_PACKET):
                        occluded_packet(bvh, root2, org2, dirs2, tmin, tmax, lo, min(SHADOW_PACKET, nd - lo), work, occ,
                                        sh_node, sh_tri)
                    for d in range(nd):
                        k = drawn[d]
                        value[k] += (1.0 - np.float64(occ[d]) - value[k]) / prob[k]
                        counts[px, SH_TRI] += sh_tri[d]
                        counts[px, SH_NODE] += sh_node[d]
                    l0, l1, l2 = batch.emitted[i, 0] + a0, batch.emitted[i, 1] + a1, batch.emitted[i, 2] + a2
                    for k in range(m):
                        v = value[k]
                        l0 += contrib[k, 0] * v
                        l1 += contrib[k, 1] * v
                        l2 += contrib[k, 2] * v
                        counts[px, NEGATIVE] += v < 0.0
                    n_seg[px] += m
                    traced[px] += nd
                    radiance[i, 0], radiance[i, 1], radiance[i, 2] = l0, l1, l2
    return radiance, counts, n_seg, traced
