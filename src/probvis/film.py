"""The last stage of a render: the film. As Mitsuba's `hdrfilm` (its `ImageBlock`), each camera sample adds w·L
and w to every pixel of the rendered window its reconstruction filter covers, w the filter at the pixel centre's
offset from the sample, and a pixel is Σ w·L / Σ w; the box filter keeps each sample in its own pixel (w = 1).
Beside the image, per pixel of the samples' origin (they describe the work and the samples there, not light):
the second moment, the test counts, case shares and the estimator's AOVs.

Splatting runs in two passes without races, so that an image depends only on the seed (`splat`): per pixel, its
samples' sums for each pixel they may reach; per pixel of the image, its neighbours' sums in a fixed order.
"""
import math
import time
import warnings
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from .cases import CASE_MASK, N_CASES
from .shading import CAM_NODE, CAM_TRI, N_COUNTS, SH_NODE, SH_TRI

BLACK = float(np.finfo(np.float32).tiny)  # below the smallest normal value of a 32-bit EXR: black


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


FILTER_TENT, FILTER_GAUSSIAN, FILTER_CUBIC, FILTER_LANCZOS = 1, 2, 3, 4
SPLAT_CHUNK_BYTES = 1 << 20  # the per-pixel blocks of one splat call, to stay in cache: batches go in chunks
SPLAT_MIN_ROWS = 8  # ... of at least this many times the filter's reach in rows, so that the rows a chunk
# reaches beyond its own (the reach above and below) add at most a quarter to its second pass


class SplatFilter(NamedTuple):
    """A reconstruction filter that splats, as the `splat` kernel takes it: Mitsuba's `tent`, `gaussian` (radius
    4 stddev, shifted down to zero there), Mitchell and Netravali's cubic (`mitchell`, and `catmullrom`: B = 0,
    C = 1/2; radius 2) and `lanczos` (its lobes as radius), the last two with negative lobes."""

    kind: int  # FILTER_TENT, FILTER_GAUSSIAN, FILTER_CUBIC or FILTER_LANCZOS
    radius: float
    alpha: float  # Gaussian: -1 / (2 stddev^2)
    bias: float  # Gaussian: its value at the radius
    b: float = 0.0  # cubic: Mitchell and Netravali's B
    c: float = 0.0  # cubic: their C


def splat_chunk(rfilter, width):
    """(pixels, bytes) of one call of `splat` for a film `width` pixels wide: its blocks within
    SPLAT_CHUNK_BYTES, or SPLAT_MIN_ROWS times the filter's reach in rows."""
    reach = max(0, math.ceil(rfilter.radius - 0.5))
    per_pixel = 8 * 5 * (2 * reach + 1) ** 2
    pixels = max(1, SPLAT_CHUNK_BYTES // per_pixel, SPLAT_MIN_ROWS * reach * width)
    return pixels, pixels * per_pixel


def splat_filter(camera, filter_importance=False):
    """The `SplatFilter` of a `scene.Camera`'s reconstruction filter, or None where samples are not splatted: a
    box filter, or samples drawn from the filter (`filter_importance`)."""
    if camera.rfilter == "box" or filter_importance:
        return None
    radius = float(camera.filter_extent)
    if camera.rfilter == "tent":
        return SplatFilter(FILTER_TENT, radius, 0.0, 0.0)
    if camera.rfilter in ("mitchell", "catmullrom"):
        b, c = (camera.filter_b, camera.filter_c) if camera.rfilter == "mitchell" else (0.0, 0.5)
        return SplatFilter(FILTER_CUBIC, radius, 0.0, 0.0, float(b), float(c))
    if camera.rfilter == "lanczos":
        return SplatFilter(FILTER_LANCZOS, radius, 0.0, 0.0)
    alpha = -1.0 / (2.0 * camera.filter_stddev ** 2)
    return SplatFilter(FILTER_GAUSSIAN, radius, alpha, math.exp(alpha * radius * radius))


# A Gaussian's exponent over its radius (Mitsuba's: 4 stddev) spans [-8, 0]: exp(x) = exp(x / 16)^16, the inner
# one by its Taylor polynomial of degree 13 (remainder below 1e-15 on [-0.5, 0]), then squared four times.
_EXP_TAYLOR = tuple(1.0 / math.factorial(n) for n in range(14))
SPLAT_GROUP = 16  # source pixels per parallel task of the splat, which share its scratch arrays


@njit(cache=True, error_model="numpy", fastmath={"reassoc", "contract"})
def _filter_rows(f, d0, out):
    """out[k, s] = the filter at d0[s] + k pixels from sample s, for all samples in one loop that the compiler
    vectorises: arithmetic only, no libm call (exp as `_EXP_TAYLOR` says, within 1e-14 of it)."""
    n_k, n = out.shape
    if f.kind == FILTER_TENT:
        inv = 1.0 / f.radius
        for k in range(n_k):
            for s in range(n):
                out[k, s] = max(0.0, 1.0 - abs(d0[s] + k) * inv)
        return
    if f.kind == FILTER_CUBIC:  # Mitchell and Netravali (1988), as Mitsuba evaluates it
        b, c = f.b, f.c
        i3, i2, i0 = (12.0 - 9.0 * b - 6.0 * c) / 6.0, (-18.0 + 12.0 * b + 6.0 * c) / 6.0, (6.0 - 2.0 * b) / 6.0
        o3, o2, o1, o0 = (-b - 6.0 * c) / 6.0, (6.0 * b + 30.0 * c) / 6.0, (-12.0 * b - 48.0 * c) / 6.0, \
            (8.0 * b + 24.0 * c) / 6.0
        for k in range(n_k):
            for s in range(n):
                x = abs(d0[s] + k)
                inner = (i3 * x + i2) * x * x + i0
                outer = ((o3 * x + o2) * x + o1) * x + o0
                out[k, s] = inner if x < 1.0 else (outer if x < 2.0 else 0.0)
        return
    if f.kind == FILTER_LANCZOS:  # sinc(x) sinc(x / lobes) within the lobes
        r = f.radius
        for k in range(n_k):
            for s in range(n):
                x = abs(d0[s] + k)
                x1 = math.pi * x
                x2 = x1 / r
                out[k, s] = 1.0 if x < 1e-7 else (math.sin(x1) * math.sin(x2) / (x1 * x2) if x <= r else 0.0)
        return
    r2, a = f.radius * f.radius, f.alpha / 16.0
    c = _EXP_TAYLOR
    for k in range(n_k):
        for s in range(n):
            d = d0[s] + k
            y = min(d * d, r2) * a
            e = c[0] + y * (c[1] + y * (c[2] + y * (c[3] + y * (c[4] + y * (c[5] + y * (c[6] + y * (c[7] + y * (
                c[8] + y * (c[9] + y * (c[10] + y * (c[11] + y * (c[12] + y * c[13]))))))))))))
            e *= e
            e *= e
            e *= e
            e *= e
            out[k, s] = max(0.0, e - f.bias)


@njit(cache=True, error_model="numpy", fastmath={"reassoc", "contract"})
def _pixel_block(wx, wy, v, out):
    """One source pixel's block from its samples s: out[ky, kx] = Σ w, Σ w·r, Σ w·g, Σ w·b, Σ w², with
    w = wy[ky, s] wx[kx, s] and v[:, s] their radiance; each sum a vectorised reduction over the samples."""
    n_k, n = wx.shape
    for ky in range(n_k):
        for kx in range(n_k):
            a0 = a1 = a2 = a3 = a4 = 0.0
            for s in range(n):
                w = wy[ky, s] * wx[kx, s]
                a0 += w
                a1 += w * v[0, s]
                a2 += w * v[1, s]
                a3 += w * v[2, s]
                a4 += w * w
            out[ky, kx, 0] = a0
            out[ky, kx, 1] = a1
            out[ky, kx, 2] = a2
            out[ky, kx, 3] = a3
            out[ky, kx, 4] = a4


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
    block = np.empty((n_src, n_k, n_k, 5))  # per source pixel and target offset: Σ w, Σ w·r, Σ w·g, Σ w·b, Σ w²
    for group in prange((n_src + SPLAT_GROUP - 1) // SPLAT_GROUP):
        d = np.empty((2, spp))  # per sample: its offset from the first pixel it may reach, in x and y
        w = np.empty((2, n_k, spp))  # the filter at the pixels it may reach, in x and y
        v = np.empty((3, spp))
        for j in range(group * SPLAT_GROUP, min(n_src, (group + 1) * SPLAT_GROUP)):
            x0, y0 = (p0 + j) % width - b + 0.5, (p0 + j) // width - b + 0.5
            for s in range(spp):
                i = j * spp + s
                d[0, s] = x0 - film_xy[i, 0]
                d[1, s] = y0 - film_xy[i, 1]
                for c in range(3):
                    v[c, s] = radiance[i, c]
            _filter_rows(f, d[0], w[0])
            _filter_rows(f, d[1], w[1])
            _pixel_block(w[0], w[1], v, block[j])
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
        self.seconds = 0.0  # spent in `add`: the film's share of the render

    def add(self, batch, shaded):
        """A `ShadedBatch` of the `ShadingBatch` `batch`: its samples' radiance, its pixels' counts and AOVs."""
        t0 = time.perf_counter()
        self._add(batch, shaded)
        self.seconds += time.perf_counter() - t0

    def _add(self, batch, shaded):
        pix = batch.pixel
        mean, self.moment2[pix] = pixel_moments(shaded.radiance, self.spp)
        if self.rfilter is None:
            self.image[pix] = mean
        else:
            if len(pix) and pix[-1] - pix[0] + 1 != len(pix):
                raise ValueError("a splatting film takes batches of consecutive pixels")
            var = np.maximum(self.moment2[pix] - mean * mean, 0.0) * (self.spp / max(self.spp - 1, 1))
            chunk = splat_chunk(self.rfilter, self.width)[0]
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
        # a filter with negative lobes may leave a pixel's weights summing below 0: divided as Mitsuba divides
        inv = np.divide(1.0, self.weight, out=np.zeros_like(self.weight), where=self.weight != 0)[:, None]
        return self.image * inv

    def noise_relmse(self):
        """relMSE (weights 1 / (x^2 + 0.01), as ../shared/README.md defines it) of the image against its own
        expectation, estimated from the per-pixel variance of the camera samples' radiance: for a box,
        (m2 - mean²) / (spp - 1); splatting, Σ w²·σ² / (Σ w)², each sample's σ² that of its own pixel's samples
        (a weighted mean of independent samples). None with one sample per pixel, whose variance is unknown."""
        if self.spp < 2:
            return None
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


def warn_if_black(image):
    """Warn of an image with nothing a file can show: no light reached the camera, which is rarely meant."""
    values = np.abs(image[np.isfinite(image)])  # NaN and infinite pixels are the image writers' to report
    peak = float(values.max()) if values.size else np.inf
    if peak < BLACK:
        warnings.warn(f"the image is black (its largest value is {peak:.3g}): no light reached the camera. Is each "
                      "emitter inside closed geometry, behind a one-sided surface, facing away from the scene or "
                      "scaled to almost nothing?", stacklevel=4)
