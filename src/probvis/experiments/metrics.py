"""Error and efficiency measures of a study.

relMSE follows ../shared/README.md (and the benchmarks): mean over pixels and channels of
(x - ref)^2 / (ref^2 + 0.01). Efficiency is the inverse of error x cost, with cost either seconds or tests.
"""
import math

import numpy as np

EPSILON = 0.01


def relmse(image, reference):
    d = np.asarray(image, dtype=np.float64) - reference
    return float(np.mean(d * d / (np.asarray(reference, dtype=np.float64) ** 2 + EPSILON)))


def rmse(image, reference):
    return float(np.sqrt(np.mean((np.asarray(image, dtype=np.float64) - reference) ** 2)))


def efficiency(error, cost):
    """1 / (error x cost); infinite when either is zero, None when unknown."""
    if error is None or cost is None:
        return None
    return math.inf if error * cost == 0 else 1.0 / (error * cost)


def time_to_target(costs, errors, target):
    """Cost at which the error reaches `target`, interpolated log-log between measured (cost, error) points.

    The points are sorted by cost; the first crossing below `target` is used. Returns None when no point
    reaches the target (no extrapolation), and the first cost when the cheapest point is already below it.
    """
    pts = sorted((c, e) for c, e in zip(costs, errors) if c is not None and e is not None and c > 0 and e > 0)
    if not pts or target is None or target <= 0:
        return None
    if pts[0][1] <= target:
        return pts[0][0]
    for (c0, e0), (c1, e1) in zip(pts, pts[1:]):
        if e1 <= target < e0:
            t = (math.log(target) - math.log(e0)) / (math.log(e1) - math.log(e0))
            return math.exp(math.log(c0) + t * (math.log(c1) - math.log(c0)))
    return None


def block_means(image, block):
    """Means of block x block pixel tiles (a partial tile at the border is dropped)."""
    h, w = image.shape[0] // block * block, image.shape[1] // block * block
    return np.asarray(image[:h, :w], dtype=np.float64).reshape(h // block, block, w // block, block, -1).mean(
        axis=(1, 3))


def block_bias_ratio(image_a, image_b, reference, block=8, trim=0.05, reference_noise=0.0):
    """Is a method converging to the reference? Two renders with different seeds: block means' squared error
    against the reference over half their squared difference (the noise), both weighted like relMSE; about 1
    (1-2.5: heavy-tailed pixels) for an unbiased method, far more for a biased one. The `trim` share of blocks
    with the largest seed-to-seed difference is left out; `reference_noise` is the reference's own per-pixel
    relMSE, which matters where a method is noise-free (analytically lit regions)."""
    block = min(block, *np.shape(reference)[:2])  # an image smaller than a block is one block
    a, b, r = block_means(image_a, block), block_means(image_b, block), block_means(reference, block)
    weight = 1.0 / (r * r + EPSILON)
    err = ((a - r) ** 2 * weight).mean(axis=-1).ravel()
    noise = ((a - b) ** 2 * weight).mean(axis=-1).ravel() / 2
    keep = noise <= np.quantile(noise, 1 - trim)
    return float(err[keep].mean()) / max(float(noise[keep].mean()) + reference_noise / block ** 2, 1e-30)
