"""Between emitter sampling and visibility: shadow-segment slots, compacted into the estimator's `ShadowQuery`.

Emitter sampling writes `shadow_rays` slots per camera sample, some inactive (the emitter point faces away);
`compact` gathers the active ones, in slot order, into dense segment arrays.
"""
import numpy as np
from numba import njit, prange

from .rng import mix64

SHADOW_EPSILON = 1e-6  # segments stop this fraction short of the emitter point


class SegmentBuffers:
    """Slot and segment arrays reused by every batch of a render: fresh multi-megabyte arrays per batch cost
    more in page faults than the kernels that fill them."""

    def __init__(self, n_slots):
        self.s_org, self.s_dir, self.contrib = (np.empty((n_slots, 3)) for _ in range(3))
        self.s_emit = np.empty(n_slots, np.int32)
        self.active = np.empty(n_slots, np.bool_)
        self.org, self.dirs = np.empty((n_slots, 3)), np.empty((n_slots, 3))
        self.point = np.empty(n_slots, np.int64)
        self.emit = np.empty(n_slots, np.int32)
        self.key = np.empty(n_slots, np.uint64)
        self.weight = np.empty(n_slots)
        self.tmax = np.full(n_slots, 1.0 - SHADOW_EPSILON)

    def slots(self, m):
        """The first m slots: origin, direction, contribution, emitter, active."""
        return self.s_org[:m], self.s_dir[:m], self.contrib[:m], self.s_emit[:m], self.active[:m]

    def segments(self):
        """The dense segment arrays `compact` fills: origin, direction, camera sample, emitter, rng key, weight."""
        return self.org, self.dirs, self.point, self.emit, self.key, self.weight


@njit(cache=True, parallel=True, error_model="numpy")
def compact(active, s_org, s_dir, s_emit, contrib, keys, n_shadow, org, dirs, point, emit, rkey, weight):
    """Gather the active shadow slots into the front of the dense arrays, in slot order, with each segment's
    `weight`: the luminance of its unoccluded contribution.

    Returns `offsets`: `offsets[i]:offsets[i + 1]` is the dense range of camera sample i (so the film can
    walk it) and `offsets[-1]` the number of segments.
    """
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
                    org[k, c] = s_org[slot, c]
                    dirs[k, c] = s_dir[slot, c]
                point[k] = i
                emit[k] = s_emit[slot]
                weight[k] = 0.212671 * contrib[slot, 0] + 0.715160 * contrib[slot, 1] + 0.072169 * contrib[slot, 2]
                rkey[k] = mix64(keys[i] + np.uint64(j + 1))
                k += 1
    return offsets
