"""The last stage of a render: the film. As Mitsuba's `hdrfilm` (its `ImageBlock`), each camera sample adds w·L
and w to every pixel of the rendered window its reconstruction filter covers, w the filter at the pixel centre's
offset from the sample, and a pixel is Σ w·L / Σ w; the box filter keeps each sample in its own pixel (w = 1).
Beside the image, per pixel of the samples' origin (they describe the work and the samples there, not light):
the second moment, the test counts, case shares and the estimator's AOVs.

Splatting runs in two passes without races, so that an image depends only on the seed (`splat`): per pixel, its
samples' sums for each pixel they may reach; per pixel of the image, its neighbours' sums in a fixed order.
"""
import math
from typing import NamedTuple

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


FILTER_TENT, FILTER_GAUSSIAN = 1, 2
SPLAT_CHUNK_BYTES = 32 << 20  # the splat's per-pixel blocks of one call: batches are splatted in chunks of this


class SplatFilter(NamedTuple):
    """A reconstruction filter that splats (Mitsuba's `tent` and `gaussian`, radius 4 stddev, shifted down to
    zero there), as the `splat` kernel takes it."""

    kind: int  # FILTER_TENT or FILTER_GAUSSIAN
    radius: float
    alpha: float  # Gaussian: -1 / (2 stddev^2)
    bias: float  # Gaussian: its value at the radius


def splat_filter(camera, filter_importance=False):
    """The `SplatFilter` of a `scene.Camera`'s reconstruction filter, or None where samples are not splatted: a
    box filter, or samples drawn from the filter (`filter_importance`)."""
    if camera.rfilter == "box" or filter_importance:
        return None
    radius = float(camera.filter_extent)
    if camera.rfilter == "tent":
        return SplatFilter(FILTER_TENT, radius, 0.0, 0.0)
    alpha = -1.0 / (2.0 * camera.filter_stddev ** 2)
    return SplatFilter(FILTER_GAUSSIAN, radius, alpha, math.exp(alpha * radius * radius))


@njit(cache=True, error_model="numpy", inline="always")
def _filter_row(f, d0, step, out, i):
    """out[i, k] = the filter at offsets d0, d0 + 1, ... (pixels); a Gaussian's by the recurrence
    exp(a(d+1)²) = exp(ad²)·exp(a(2d+1)), whose factor grows by `step` = exp(2a) each pixel: two exp calls a row."""
    if f.kind == FILTER_TENT:
        for k in range(out.shape[1]):
            out[i, k] = max(0.0, 1.0 - abs(d0 + k) / f.radius)
        return
    e = math.exp(f.alpha * d0 * d0)
    g = math.exp(f.alpha * (2.0 * d0 + 1.0))
    for k in range(out.shape[1]):
        out[i, k] = max(0.0, e - f.bias)
        e *= g
        g *= step


@njit(cache=True, parallel=True, error_model="numpy")
def splat(f, film_xy, radiance, var, p0, spp, width, height, wsum, wl, wvar):
    """Add the camera samples of pixels p0, p0 + 1, ... (row-major, `spp` each, film positions `film_xy`; `var`
    the sample variance of each pixel's samples) to the weight sums `wsum`, Σ w·L `wl` and Σ w²·σ² `wvar` (σ²
    that of the sample's own pixel) of every pixel their filter covers.

    Two passes, each without races: per source pixel, the sums over its samples for each pixel its filter may
    reach (a block of (2b + 1)² entries); then per target pixel, the blocks of its neighbours, in a fixed order."""
    b = max(0, int(math.ceil(f.radius - 0.5)))
    n_k = 2 * b + 1
    n_src = radiance.shape[0] // spp
    p1 = p0 + n_src
    block = np.zeros((n_src, n_k, n_k, 5))  # per source pixel and target offset: Σ w, Σ w·r, Σ w·g, Σ w·b, Σ w²
    step = math.exp(2.0 * f.alpha)
    for j in prange(n_src):
        src = p0 + j
        wx = np.empty((1, n_k))  # the filter at the pixels a sample may reach, from its pixel - b on
        wy = np.empty((1, n_k))
        x0, y0 = src % width - b + 0.5, src // width - b + 0.5
        for i in range(j * spp, (j + 1) * spp):
            _filter_row(f, x0 - film_xy[i, 0], step, wx, 0)
            _filter_row(f, y0 - film_xy[i, 1], step, wy, 0)
            r, g, bl = radiance[i, 0], radiance[i, 1], radiance[i, 2]
            for ky in range(n_k):
                for kx in range(n_k):
                    w = wx[0, kx] * wy[0, ky]
                    block[j, ky, kx, 0] += w
                    block[j, ky, kx, 1] += w * r
                    block[j, ky, kx, 2] += w * g
                    block[j, ky, kx, 3] += w * bl
                    block[j, ky, kx, 4] += w * w
    row0 = max(p0 // width - b, 0)
    row1 = min((p1 - 1) // width + b, height - 1)
    for t in prange((row1 - row0 + 1) * width):
        ty, tx = row0 + t // width, t % width
        q = ty * width + tx
        for sy in range(max(ty - b, 0), min(ty + b, height - 1) + 1):
            for sx in range(max(tx - b, 0), min(tx + b, width - 1) + 1):
                j = sy * width + sx - p0
                if j < 0 or j >= n_src:
                    continue
                ky, kx = ty - sy + b, tx - sx + b
                wsum[q] += block[j, ky, kx, 0]
                for c in range(3):
                    wl[q, c] += block[j, ky, kx, 1 + c]
                    wvar[q, c] += block[j, ky, kx, 4] * var[j, c]


class Film:
    """Everything a render accumulates per pixel, filled batch by batch (`add`: a batch of whole pixels, in
    order); `rfilter` is a `SplatFilter` (None: the box filter)."""

    def __init__(self, width, height, spp, n_emitters, segment_aovs=(), rfilter=None):
        n = width * height
        self.width, self.height, self.spp, self.n_emitters = width, height, spp, n_emitters
        self.rfilter = rfilter
        self.image = np.zeros((n, 3))  # box: the pixel's mean; splatting: Σ w·L
        self.moment2 = np.zeros((n, 3))  # the mean square of each pixel's own samples
        if rfilter is not None:
            self.weight = np.zeros(n)  # Σ w
            self.weighted_var = np.zeros((n, 3))  # Σ w²·σ², σ² of the samples of each sample's own pixel
        self.counts = np.zeros((n, N_COUNTS), np.int64)
        self.case_counts = None  # (n, emitters, N_CASES) samples per case, once an estimator classifies
        self.segment_aovs = {name: np.zeros(n) for name in segment_aovs}

    def add(self, batch, shaded):
        """A `ShadedBatch` of the `ShadingBatch` `batch`: its samples' radiance, its pixels' counts and AOVs."""
        pix = batch.pixel
        mean, self.moment2[pix] = pixel_moments(shaded.radiance, self.spp)
        if self.rfilter is None:
            self.image[pix] = mean
        else:
            if len(pix) and pix[-1] - pix[0] + 1 != len(pix):
                raise ValueError("a splatting film takes batches of consecutive pixels")
            var = np.maximum(self.moment2[pix] - mean * mean, 0.0) * (self.spp / max(self.spp - 1, 1))
            reach = max(0, math.ceil(self.rfilter.radius - 0.5))
            chunk = max(1, SPLAT_CHUNK_BYTES // (8 * 5 * (2 * reach + 1) ** 2))  # pixels whose blocks fit
            for c0 in range(0, len(pix), chunk):
                rows = slice(c0 * self.spp, min(len(pix), c0 + chunk) * self.spp)
                splat(self.rfilter, batch.film_xy[rows], shaded.radiance[rows], var[c0:c0 + chunk],
                      int(pix[0]) + c0, self.spp, self.width, self.height, self.weight, self.image,
                      self.weighted_var)
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

    def _mean(self):
        """Per pixel: the (weighted) mean of the samples' radiance."""
        if self.rfilter is None:
            return self.image
        inv = np.divide(1.0, self.weight, out=np.zeros_like(self.weight), where=self.weight > 0)[:, None]
        return self.image * inv

    def noise_relmse(self):
        """relMSE (weights 1 / (x^2 + 0.01), as ../shared/README.md defines it) of the image against its own
        expectation, estimated from the per-pixel variance of the camera samples' radiance: for a box,
        (m2 - mean²) / (spp - 1); splatting, Σ w²·σ² / (Σ w)², each sample's σ² that of its own pixel's samples
        (a weighted mean of independent samples)."""
        mean = self._mean()
        if self.rfilter is None:
            var = np.maximum(self.moment2 - mean * mean, 0.0) / max(self.spp - 1, 1)
        else:
            w2 = self.weight ** 2
            var = np.divide(self.weighted_var, w2[:, None], out=np.zeros_like(self.weighted_var),
                            where=w2[:, None] > 0)
        return float(np.mean(var / (mean * mean + 0.01)))

    def developed(self):
        """The (height, width, 3) radiance image: each pixel's (weighted) mean, 0 where no sample reached it."""
        return self._mean().reshape(self.height, self.width, 3)
