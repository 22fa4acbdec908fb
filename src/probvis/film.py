"""Stage 5 of a render: the film. Camera samples' radiance is averaged per pixel (box filter), with the
second moment, per-pixel test counts and the estimator's AOVs beside it."""
import numpy as np
from numba import njit, prange

from .cases import CASE_MASK, N_CASES

N_COUNTS = 5  # per-pixel counts: camera-ray triangle and node tests, shadow triangle and node tests, negatives
CAM_TRI, CAM_NODE, SH_TRI, SH_NODE, NEGATIVE = range(N_COUNTS)


@njit(cache=True, error_model="numpy", inline="always")
def add_sample(img, m2, q, l0, l1, l2):
    """Add one camera sample's radiance to pixel q's sum and sum of squares."""
    img[q, 0] += l0
    img[q, 1] += l1
    img[q, 2] += l2
    m2[q, 0] += l0 * l0
    m2[q, 1] += l1 * l1
    m2[q, 2] += l2 * l2


@njit(cache=True, error_model="numpy", inline="always")
def pixel_mean(img, m2, q, spp):
    """Turn pixel q's sums over its spp samples into means (box filter)."""
    for c in range(3):
        img[q, c] /= spp
        m2[q, c] /= spp


@njit(cache=True, parallel=True, error_model="numpy")
def accumulate(emitted, contrib, active, offsets, value, cam_node, cam_tri, sh_node, sh_tri, spp, n_shadow, n_pix):
    """Pixel means of a batch of whole pixels: each camera sample's `emitted` radiance plus, over its active
    shadow slots, unoccluded contribution x visibility estimate (`value`, dense: `offsets[i]` onwards for camera
    sample i). Returns the means, the second moments and the per-pixel counts (see N_COUNTS)."""
    img = np.zeros((n_pix, 3))
    m2 = np.zeros((n_pix, 3))
    counts = np.zeros((n_pix, N_COUNTS), np.int64)
    for q in prange(n_pix):
        for s in range(spp):
            i = q * spp + s
            counts[q, CAM_TRI] += cam_tri[i]
            counts[q, CAM_NODE] += cam_node[i]
            l0, l1, l2 = emitted[i, 0], emitted[i, 1], emitted[i, 2]
            k = offsets[i]
            for j in range(n_shadow):
                slot = i * n_shadow + j
                if active[slot]:
                    v = value[k]
                    l0 += contrib[slot, 0] * v
                    l1 += contrib[slot, 1] * v
                    l2 += contrib[slot, 2] * v
                    counts[q, SH_TRI] += sh_tri[k]
                    counts[q, SH_NODE] += sh_node[k]
                    counts[q, NEGATIVE] += v < 0.0
                    k += 1
            add_sample(img, m2, q, l0, l1, l2)
        pixel_mean(img, m2, q, spp)
    return img, m2, counts


class Film:
    """Everything a render accumulates per pixel, filled batch by batch (pixels [p0, p1) at a time)."""

    def __init__(self, width, height, spp, n_emitters, segment_aovs=()):
        n = width * height
        self.width, self.height, self.spp, self.n_emitters = width, height, spp, n_emitters
        self.image = np.zeros((n, 3))
        self.moment2 = np.zeros((n, 3))
        self.counts = np.zeros((n, N_COUNTS), np.int64)
        self.case_counts = None  # (n, emitters, N_CASES) samples per case, once an estimator classifies
        self.segment_aovs = {name: np.zeros(n) for name in segment_aovs}

    def store(self, p0, p1, img, m2, counts):
        """The means, second moments and counts of pixels [p0, p1)."""
        self.image[p0:p1], self.moment2[p0:p1], self.counts[p0:p1] = img, m2, counts

    def add_cases(self, p0, p1, cases):
        """Count the occlusion cases (camera samples x emitters, CASE_*) of pixels [p0, p1)."""
        if self.case_counts is None:
            self.case_counts = np.zeros((len(self.image), self.n_emitters, N_CASES), np.int32)
        per_px = cases.reshape(p1 - p0, self.spp, -1) & CASE_MASK
        for c in range(N_CASES):
            self.case_counts[p0:p1, :, c] = (per_px == c).sum(axis=1)

    def add_segment_aovs(self, p0, p1, sample, values):
        """Add per-segment AOV `values` (name -> (n,)) of segments made by camera samples `sample` (batch indices)."""
        pixel = sample // self.spp
        for name, v in values.items():
            self.segment_aovs[name][p0:p1] += np.bincount(pixel, weights=v, minlength=p1 - p0) / self.spp

    def totals(self):
        """Counts summed over the image, by name."""
        return dict(zip(("cam_tri", "cam_node", "sh_tri", "sh_node", "negative"), map(int, self.counts.sum(axis=0))))

    def aovs(self):
        """Per-pixel images besides radiance: test counts, second moment, case shares, the estimator's AOVs."""
        shape = (self.height, self.width)
        out = {
            "triangle_tests": (self.counts[:, CAM_TRI] + self.counts[:, SH_TRI]).reshape(shape),
            "node_tests": (self.counts[:, CAM_NODE] + self.counts[:, SH_NODE]).reshape(shape),
            "second_moment": self.moment2.reshape(shape + (3,)),
        }
        if self.case_counts is not None:
            out["cases"] = (self.case_counts / self.spp).reshape(shape + self.case_counts.shape[1:])
        for name, v in self.segment_aovs.items():
            out[name] = v.reshape(shape)
        return out

    def noise_relmse(self):
        """relMSE (weights 1 / (x^2 + 0.01), as ../shared/README.md defines it) of the image against its own
        expectation, estimated from the per-pixel variance of the camera samples' radiance."""
        var = np.maximum(self.moment2 - self.image * self.image, 0.0) / max(self.spp - 1, 1)
        return float(np.mean(var / (self.image * self.image + 0.01)))

    def developed(self):
        """The (height, width, 3) radiance image."""
        return self.image.reshape(self.height, self.width, 3)
