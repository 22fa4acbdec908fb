"""The staged render path's middle: shadow-segment slots filled per shading point, compacted into the
estimator's `ShadowQuery`, and each camera sample's radiance from the estimates the estimator returns.

Emitter sampling writes `shadow_rays` slots per camera sample, some inactive (the emitter point faces away);
`compact` gathers the active ones, in slot order, into dense segment arrays; `sample_radiance` adds each
segment's unoccluded contribution times its estimate to its camera sample's radiance.
"""
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from .color import luminance
from .rng import mix64
from .shading import CAM_NODE, CAM_TRI, NEGATIVE, SH_NODE, SH_TRI, SHADOW_EPSILON, point_samples, shaded_arrays

POINTS_PER_BLOCK = 64  # shading points per parallel work item of `sample_emitters`


class ShadowSlots(NamedTuple):
    """`shadow_rays` slots per camera sample, as emitter sampling fills them (an inactive slot's other fields are
    meaningless)."""

    origin: np.ndarray  # (n, 3) segment origin, off the surface
    direction: np.ndarray  # (n, 3) emitter point minus origin
    contrib: np.ndarray  # (n, 3) unoccluded contribution (divided by pdf and shadow rays)
    emitter: np.ndarray  # (n,) int32
    active: np.ndarray  # (n,) bool: the emitter point and the shading point face each other


class Segments(NamedTuple):
    """The active slots, dense: what `ShadowQuery` shows the estimator."""

    origin: np.ndarray  # (n, 3)
    direction: np.ndarray  # (n, 3)
    point: np.ndarray  # (n,) int64 camera sample (index in the batch)
    emitter: np.ndarray  # (n,) int32
    key: np.ndarray  # (n,) uint64 per-segment rng key
    weight: np.ndarray  # (n,) luminance of the unoccluded contribution
    tmax: np.ndarray  # (n,) 1 - SHADOW_EPSILON


class SegmentBuffers:
    """Slot and segment arrays reused by every batch of a render: fresh multi-megabyte arrays per batch cost
    more in page faults than the kernels that fill them."""

    def __init__(self, n_slots):
        self.all_slots = ShadowSlots(np.empty((n_slots, 3)), np.empty((n_slots, 3)), np.empty((n_slots, 3)),
                                     np.empty(n_slots, np.int32), np.empty(n_slots, np.bool_))
        self.dense = Segments(np.empty((n_slots, 3)), np.empty((n_slots, 3)), np.empty(n_slots, np.int64),
                              np.empty(n_slots, np.int32), np.empty(n_slots, np.uint64), np.empty(n_slots),
                              np.full(n_slots, 1.0 - SHADOW_EPSILON))

    def slots(self, m):
        """The first m slots."""
        return ShadowSlots(*(a[:m] for a in self.all_slots))

    def segments(self, n):
        """The first n dense segments."""
        return Segments(*(a[:n] for a in self.dense))


@njit(cache=True, parallel=True, error_model="numpy")
def sample_emitters(geom, es, batch, slots, threads):
    """`shading.point_samples` of every camera sample of the batch, sample i in slots i * shadow_rays onwards;
    returns the analytic radiance (of lit emitters) per camera sample. `threads` is the thread budget (lanes)."""
    s_org, s_dir, contrib, s_emit, active = slots  # kernels write through plain arrays, never through a record
    unused = np.empty(0, np.int64)  # the dense-only sample indices
    n = batch.triangle.shape[0]
    analytic = np.zeros((n, 3))
    n_blocks = (n + POINTS_PER_BLOCK - 1) // POINTS_PER_BLOCK
    lanes = min(threads, n_blocks)
    for lane in prange(lanes):  # one lane of blocks per thread (see `parallel`)
        for blk in range(lane, n_blocks, lanes):
            for i in range(blk * POINTS_PER_BLOCK, min(n, (blk + 1) * POINTS_PER_BLOCK)):
                analytic[i, 0], analytic[i, 1], analytic[i, 2] = point_samples(
                    i, geom, es, batch, i * batch.shadow_rays, s_org, s_dir, contrib, s_emit, active, unused, False)[:3]
    return analytic


@njit(cache=True, parallel=True, error_model="numpy")
def compact(batch, slots, dense):
    """Gather the active shadow slots into the front of the `dense` segments, in slot order, with each segment's
    `weight`: the luminance of its unoccluded contribution.

    Returns `offsets`: `offsets[i]:offsets[i + 1]` is the dense range of camera sample i (so the film can
    walk it) and `offsets[-1]` the number of segments.
    """
    org, dirs, point, emit, rkey, weight = dense.origin, dense.direction, dense.point, dense.emitter, dense.key, \
        dense.weight
    keys, n_shadow, active = batch.keys, batch.shadow_rays, slots.active
    n = keys.shape[0]
    counts = np.zeros(n + 1, np.int64)
    for i in prange(n):
        c = 0
        for j in range(n_shadow):
            c += active[i * n_shadow + j]
        counts[i + 1] = c
    offsets = np.cumsum(counts)
    for i in prange(n):
        k = offsets[i]
        for j in range(n_shadow):
            slot = i * n_shadow + j
            if active[slot]:
                for c in range(3):
                    org[k, c] = slots.origin[slot, c]
                    dirs[k, c] = slots.direction[slot, c]
                point[k] = i
                emit[k] = slots.emitter[slot]
                weight[k] = luminance(slots.contrib[slot, 0], slots.contrib[slot, 1], slots.contrib[slot, 2])
                rkey[k] = mix64(keys[i] + np.uint64(j + 1))
                k += 1
    return offsets


@njit(cache=True, parallel=True, error_model="numpy")
def sample_radiance(batch, emitted, slots, offsets, value, sh_node, sh_tri):
    """Each camera sample's radiance: its `emitted` radiance (seen directly, plus the analytic light of lit
    emitters) plus, over its active shadow slots, unoccluded contribution x visibility estimate (`value`,
    dense: `offsets[i]` onwards for camera sample i); and the per-pixel counts (`shading.N_COUNTS`) and
    segments. Returned as `ShadedBatch`'s arrays."""
    spp, n_shadow = batch.spp, batch.shadow_rays
    cam_tri, cam_node, contrib, active = batch.cam_tri, batch.cam_node, slots.contrib, slots.active
    radiance, counts, segments = shaded_arrays(batch)
    for px in prange(counts.shape[0]):
        for s in range(spp):
            i = px * spp + s
            counts[px, CAM_TRI] += cam_tri[i]
            counts[px, CAM_NODE] += cam_node[i]
            l0, l1, l2 = emitted[i, 0], emitted[i, 1], emitted[i, 2]
            k = offsets[i]
            for j in range(n_shadow):
                slot = i * n_shadow + j
                if active[slot]:
                    v = value[k]
                    l0 += contrib[slot, 0] * v
                    l1 += contrib[slot, 1] * v
                    l2 += contrib[slot, 2] * v
                    counts[px, SH_TRI] += sh_tri[k]
                    counts[px, SH_NODE] += sh_node[k]
                    counts[px, NEGATIVE] += v < 0.0
                    k += 1
            segments[px] += k - offsets[i]
            radiance[i, 0], radiance[i, 1], radiance[i, 2] = l0, l1, l2
    return radiance, counts, segments
