"""Stage 1 of a render: primary rays of a Mitsuba `perspective` or `thinlens` sensor.

As in Mitsuba, a pixel's camera samples are uniform inside it, and the film (`film`) splats each one over the
pixels its reconstruction filter covers, at the sample's film position, which `camera_rays` returns. With
filter importance sampling (`RenderSettings.filter_importance`) the sample positions are drawn instead from the
filter centred on the pixel, each with weight 1 and only for that pixel: a pixel's expected value is then exactly
the filter-weighted mean of the radiance around it, but it averages only its own samples, so it is noisier.
Like Mitsuba's `hdrfilm` (without `sample_border`), only the rendered window is sampled: near its border the
filter is cut off there.
"""
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .errors import ProbvisError
from .parallel import over_threads
from .rng import make_key, mix64, uniform

STREAM_CAMERA = 1  # rng stream of camera paths
FILTER_BINS = 2048  # bins of a tabulated filter's inverse CDF (piecewise-constant density)
_LENS_SALT = np.uint64(0x4C454E53)  # the lens sample's key, apart from the camera sample's own dimensions


class CameraParams(NamedTuple):
    """A `scene.Camera` as the kernel takes it: half-extents of the image plane at distance 1, the crop window
    in the film, the principal-point shift, the thin lens and the filter's table (empty: uniform in the pixel)."""

    to_world: np.ndarray
    tan_x: float
    tan_y: float
    width: int
    height: int
    near_clip: float
    far_clip: float
    film_width: int
    film_height: int
    crop_x: int
    crop_y: int
    principal_x: float
    principal_y: float
    aperture_radius: float
    focus_distance: float
    filter_cdf: np.ndarray
    filter_radius: float


def filter_table(kind, radius, stddev):
    """(CDF over FILTER_BINS equal bins of [-r, r], r) of a separable Mitsuba filter that is nowhere negative;
    box: (empty, 0.5)."""
    if kind == "box":
        return np.zeros(0), 0.5
    if kind == "tent":
        r = radius
        x = (np.arange(FILTER_BINS) + 0.5) / FILTER_BINS * 2 * r - r
        f = np.maximum(0.0, 1.0 - np.abs(x) / r)
    elif kind == "gaussian":
        r = 4.0 * stddev  # Mitsuba's radius, where its Gaussian is shifted down to zero
        x = (np.arange(FILTER_BINS) + 0.5) / FILTER_BINS * 2 * r - r
        f = np.maximum(0.0, np.exp(-x * x / (2 * stddev * stddev)) - math.exp(-r * r / (2 * stddev * stddev)))
    else:  # Mitchell and Netravali's cubics, Lanczos's sinc
        raise ProbvisError(f"filter importance sampling (--filter-importance) draws camera samples from the "
                           f"reconstruction filter, and the scene's {kind} filter has negative lobes: render without "
                           "it (the film splats each sample over the filter, as Mitsuba does)")
    cdf = np.concatenate([[0.0], np.cumsum(f)])
    return cdf / cdf[-1], float(r)


def camera_params(cam, filter_importance=False):
    """The kernel's `CameraParams` of a `scene.Camera`; `filter_importance` draws sample positions from the
    reconstruction filter (otherwise uniform in the pixel, for the film to splat)."""
    fw, fh = cam.film_size
    tan_x = float(np.tan(np.radians(cam.fov_x) / 2.0))
    cdf, radius = filter_table(cam.rfilter, cam.filter_radius, cam.filter_stddev) if filter_importance else \
        (np.zeros(0), float(cam.filter_extent))
    return CameraParams(np.ascontiguousarray(cam.to_world, dtype=np.float64), tan_x, tan_x * fh / fw,
                        int(cam.width), int(cam.height), float(cam.near_clip), float(cam.far_clip), int(fw), int(fh),
                        int(cam.crop_x), int(cam.crop_y), float(cam.principal_x), float(cam.principal_y),
                        float(cam.aperture_radius), float(cam.focus_distance), cdf, radius)


@njit(cache=True, error_model="numpy", inline="always")
def _filter_cdf(cdf, radius, x):
    """The tabulated filter's CDF at offset x (clamped to [-radius, radius])."""
    n = cdf.shape[0] - 1
    t = min(max((x / radius + 1.0) * 0.5 * n, 0.0), float(n))
    k = min(int(t), n - 1)
    return cdf[k] + (t - k) * (cdf[k + 1] - cdf[k])


@njit(cache=True, error_model="numpy", inline="always")
def filter_offset(cdf, radius, u, lo, hi):
    """An offset in [lo, hi] from the pixel centre with density proportional to the tabulated filter (cut off
    outside [lo, hi]: the window's edges)."""
    n = cdf.shape[0] - 1
    u = _filter_cdf(cdf, radius, lo) + u * (_filter_cdf(cdf, radius, hi) - _filter_cdf(cdf, radius, lo))
    k = min(max(np.searchsorted(cdf, u, side="right") - 1, 0), n - 1)
    width = cdf[k + 1] - cdf[k]
    t = (u - cdf[k]) / width if width > 0.0 else 0.5
    return min(max(((k + t) / n * 2.0 - 1.0) * radius, lo), hi)


def camera_rays(cam, spp, seed, pixels):
    """Rays for `pixels` of the image (row-major indices, an int64 array), `spp` per pixel, pixel-major order.

    Returns origins, unit directions, tmin, tmax, the rng key of each camera sample and its position on the
    film (n, 2): x, y in pixels from the window's top-left corner (pixel (i, j) spans [j, j + 1] x [i, i + 1]).
    """
    n = len(pixels) * spp
    out = (np.empty((n, 3)), np.empty((n, 3)), np.empty(n), np.empty(n), np.empty(n, np.uint64), np.empty((n, 2)))
    over_threads(lambda _, first, end: _camera_ray_runs(cam, spp, seed, pixels, first, end, out), n)
    return out


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def _camera_ray_runs(cam, spp, seed, pixels, first, end, out):
    """Rays first..end-1 of `camera_rays`, into `out` (its arrays). Serial and without reference counts, run on
    the thread budget (`over_threads`)."""
    org, dirs, tmin, tmax, keys, film_xy = out
    m, tan_x, tan_y, width = cam.to_world, cam.tan_x, cam.tan_y, cam.width
    near, far, fw, fh = cam.near_clip, cam.far_clip, cam.film_width, cam.film_height
    boxed = cam.filter_cdf.shape[0] == 0
    for i in range(first, end):
        pix = pixels[i // spp]
        s = i % spp
        key = make_key(seed, STREAM_CAMERA, pix * spp + s)
        px = cam.crop_x + pix % width
        py = cam.crop_y + pix // width
        if boxed:
            ux, uy = uniform(key, 0), uniform(key, 1)
            sx = (px + ux) / fw
            sy = (py + uy) / fh
            film_xy[i, 0] = pix % width + ux
            film_xy[i, 1] = pix // width + uy
        else:
            cx, cy = px + 0.5, py + 0.5  # the window is [crop_x, crop_x + width] x [crop_y, crop_y + height]
            dx = filter_offset(cam.filter_cdf, cam.filter_radius, uniform(key, 0), cam.crop_x - cx,
                               cam.crop_x + width - cx)
            dy = filter_offset(cam.filter_cdf, cam.filter_radius, uniform(key, 1), cam.crop_y - cy,
                               cam.crop_y + cam.height - cy)
            sx = (cx + dx) / fw
            sy = (cy + dy) / fh
            film_xy[i, 0] = pix % width + 0.5 + dx
            film_xy[i, 1] = pix // width + 0.5 + dy
        lx = (1.0 - 2.0 * (sx + cam.principal_x)) * tan_x
        ly = (1.0 - 2.0 * (sy + cam.principal_y)) * tan_y
        ox = oy = 0.0
        lz = 1.0
        if cam.aperture_radius > 0.0:  # thin lens: from a point of the aperture to the point in focus
            lens = mix64(key ^ _LENS_SALT)
            r = cam.aperture_radius * math.sqrt(uniform(lens, 0))
            phi = 2.0 * math.pi * uniform(lens, 1)
            ox, oy = r * math.cos(phi), r * math.sin(phi)
            f = cam.focus_distance
            lx, ly, lz = lx * f - ox, ly * f - oy, f
        inv_len = 1.0 / np.sqrt(lx * lx + ly * ly + lz * lz)
        lx *= inv_len
        ly *= inv_len
        lz *= inv_len
        wl = 0.0
        for j in range(3):
            dirs[i, j] = m[j, 0] * lx + m[j, 1] * ly + m[j, 2] * lz
            org[i, j] = m[j, 0] * ox + m[j, 1] * oy + m[j, 3]
            wl += dirs[i, j] * dirs[i, j]
        wl = np.sqrt(wl)
        for j in range(3):
            dirs[i, j] /= wl
        tmin[i] = near / lz * wl
        tmax[i] = far / lz * wl
        keys[i] = key
