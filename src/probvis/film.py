"""The last stage of a render: the film. Camera samples' radiance is averaged per pixel (box filter), with the
second moment, per-pixel test counts, case shares and the estimator's AOVs beside it."""
import numpy as np
from numba import njit, prange

from .cases import CASE_MASK, N_CASES
from .shading import CAM_NODE, CAM_TRI, N_COUNTS, SH_NODE, SH_TRI


@njit(cache=True, parallel=True, error_model="numpy")
def pixel_moments(radiance, spp):
    """Per pixel of spp consecutive camera samples: the mean of their radiance and of its square."""
    n_pix = radiance.shape[0] // spp
    img = np.zeros((n_pix, 3))
    m2 = np.zeros((n_pix, 3))
    for px in prange(n_pix):
        for s in range(spp):
            for c in range(3):
                x = radiance[px * spp + s, c]
                img[px, c] += x
                m2[px, c] += x * x
        for c in range(3):
            img[px, c] /= spp
            m2[px, c] /= spp
    return img, m2


class Film:
    """Everything a render accumulates per pixel, filled batch by batch (`add`: a batch of whole pixels)."""

    def __init__(self, width, height, spp, n_emitters, segment_aovs=()):
        n = width * height
        self.width, self.height, self.spp, self.n_emitters = width, height, spp, n_emitters
        self.image = np.zeros((n, 3))
        self.moment2 = np.zeros((n, 3))
        self.counts = np.zeros((n, N_COUNTS), np.int64)
        self.case_counts = None  # (n, emitters, N_CASES) samples per case, once an estimator classifies
        self.segment_aovs = {name: np.zeros(n) for name in segment_aovs}

    def add(self, batch, shaded):
        """A `ShadedBatch` of the `ShadingBatch` `batch`: its pixels' means, second moments, counts and AOVs."""
        pix = batch.pixel
        self.image[pix], self.moment2[pix] = pixel_moments(shaded.radiance, self.spp)
        self.counts[pix] = shaded.counts
        for name, v in (shaded.aovs or {}).items():
            self.segment_aovs[name][pix] += v

    def add_cases(self, batch):
        """Count the batch's occlusion cases (camera samples x emitters, CASE_*) per pixel."""
        if self.case_counts is None:
            self.case_counts = np.zeros((len(self.image), self.n_emitters, N_CASES), np.int32)
        per_px = batch.cases.reshape(len(batch.pixel), self.spp, -1) & CASE_MASK
        for c in range(N_CASES):
            self.case_counts[batch.pixel, :, c] = (per_px == c).sum(axis=1)

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
