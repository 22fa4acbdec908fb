"""The environment emitter (Mitsuba's `envmap` or `constant`): its radiance from a direction, which camera rays
that miss the scene see, and directions sampled towards it for shading points.

The radiance is Mitsuba's: bilinear between pixel centres of the latitude-longitude map (u = atan2(x, -z) / 2π,
v = acos(y) / π in the map's frame), the first column repeated after the last. Sampling is Mitsuba's too (its
`envmap`'s hierarchical warp): the density in (u, v) is the bilinear interpolation of luminance × sin θ between
the pixel centres, so a direction's solid-angle pdf, that density over 2π² sin θ, follows the radiance; a cell
between four pixel centres is picked by its integral (alias table), then (u, v) within it by inverting the
bilinear density, v by its marginal and u given v. A `constant` emitter (or a map whose rows all sit at the
poles) samples its cells uniformly in solid angle instead, as Mitsuba's `constant` samples the sphere.
"""
import math

import numpy as np
from numba import njit

from .alias import alias_sample, alias_table
from .color import LUMINANCE


def environment_arrays(env, scale):
    """The `env_*` fields of `emitters.EmitterArrays` (in order) for a scene's `Environment` (None: a black
    placeholder) with radiance `scale` (3,), and the integral of its luminance over the sphere (for its power)."""
    image = np.zeros((2, 1, 3)) if env is None else env.image
    h, w = image.shape[:2]
    ext = np.ascontiguousarray(np.concatenate([image, image[:, :1]], axis=1))
    lum = np.abs(ext) @ LUMINANCE

    def cells(x):  # the four corners of each cell, (4, h - 1, w)
        return np.stack([x[:-1, :-1], x[:-1, 1:], x[1:, :-1], x[1:, 1:]])

    theta = np.linspace(0.0, np.pi, h)  # of the pixel rows
    cos_t = np.cos(theta)
    solid = (2.0 * np.pi / w) * (cos_t[:-1] - cos_t[1:])[:, None] * np.ones((1, w))
    density = sampling_luminance(lum, env is not None and env.mis_compensation) * np.sin(theta)[:, None]
    mass = cells(density).mean(axis=0)  # each cell's integral of the bilinear density, times w (h - 1)
    total = mass.sum() / (w * (h - 1))
    if env is not None and not env.constant and total > 0:
        weight, cell_pdf = mass.ravel(), np.zeros(w * (h - 1))
        density = np.ascontiguousarray(density / total)
    else:
        weight = (cells(lum).max(axis=0) * solid).ravel()
        cell_pdf = weight / (weight.sum() * solid.ravel()) if weight.sum() > 0 else np.zeros_like(weight)
        density = np.zeros((1, 1))
    prob, alias = alias_table(weight)
    to_world = np.eye(3) if env is None else np.ascontiguousarray(env.to_world, np.float64)  # the kernels' one type
    integral = float((cells(lum).mean(axis=0) * solid).sum())
    fields = (ext, prob, alias, density, cell_pdf, to_world, np.linalg.inv(to_world), 0.5 / w,
              np.zeros(3) if env is None else np.asarray(scale, np.float64))
    return fields, integral


def sampling_luminance(lum, mis_compensation):
    """The luminance (h, w + 1: the first column repeated) that the map is sampled by. With Mitsuba's
    `mis_compensation` (Karlík et al., "MIS compensation", 2019) the map's mean luminance is taken off and what is
    left clamped at zero, unless the mean is within 1% of the least value (a nearly constant map): directions
    dimmer than the mean are left to BSDF sampling, so under `direct` without BSDF samples their light is
    missing from the image, in Mitsuba as here."""
    if not mis_compensation:
        return lum
    mean = lum[:, :-1].mean()
    if mean - lum[:, :-1].min() <= 0.01 * mean:
        return lum
    return np.maximum(lum - mean, 0.0)


@njit(cache=True, error_model="numpy", inline="always")
def _linear(a, b, u):
    """x in [0, 1] with density proportional to (1 - x) a + x b (a, b >= 0) for a uniform u: the inverse CDF,
    in the form that stays exact as a approaches b."""
    root = a + math.sqrt(max(0.0, a * a + u * (b * b - a * a)))
    return min(u * (a + b) / root, 1.0) if root > 0.0 else u


@njit(cache=True, error_model="numpy", inline="always")
def environment_radiance(es, dx, dy, dz):
    """Mitsuba's envmap radiance (before its scale) arriving from world direction d (any length); `es` is the
    `EmitterArrays`."""
    m = es.env_to_local
    x = m[0, 0] * dx + m[0, 1] * dy + m[0, 2] * dz
    y = m[1, 0] * dx + m[1, 1] * dy + m[1, 2] * dz
    z = m[2, 0] * dx + m[2, 1] * dy + m[2, 2] * dz
    r = math.sqrt(x * x + y * y + z * z)
    u = math.atan2(x, -z) * (0.5 / math.pi) - es.env_shift
    u -= math.floor(u)
    v = math.acos(min(max(y / r, -1.0), 1.0)) / math.pi
    h, w1 = es.env_image.shape[0], es.env_image.shape[1]
    return _bilinear(es.env_image, u * (w1 - 1), v * (h - 1))


@njit(cache=True, error_model="numpy", inline="always")
def _bilinear(image, fx, fy):
    """Bilinear interpolation of `image` at pixel coordinates (fx, fy), pixel (i, j) at (j, i)."""
    i = min(int(fy), image.shape[0] - 2)
    j = min(int(fx), image.shape[1] - 2)
    wx, wy = fx - j, fy - i
    return _lerp2(image, i, j, wx, wy, 0), _lerp2(image, i, j, wx, wy, 1), _lerp2(image, i, j, wx, wy, 2)


@njit(cache=True, error_model="numpy", inline="always")
def _lerp2(image, i, j, wx, wy, c):
    """Channel c of the bilinear blend of pixels (i, j)..(i + 1, j + 1) with weights (wx, wy)."""
    top = (1.0 - wx) * image[i, j, c] + wx * image[i, j + 1, c]
    bottom = (1.0 - wx) * image[i + 1, j, c] + wx * image[i + 1, j + 1, c]
    return (1.0 - wy) * top + wy * bottom


@njit(cache=True, error_model="numpy", inline="always")
def sample_environment(es, u1, u2, u3):
    """A world direction towards the environment (`es`: the `EmitterArrays`), by its cells: (dx, dy, dz,
    solid-angle pdf, and the radiance r, g, b before the emitter's scale)."""
    h, w = es.env_image.shape[0], es.env_image.shape[1] - 1
    k = alias_sample(es.env_cell_prob, es.env_cell_alias, 0, es.env_cell_prob.shape[0], u1)
    i, j = k // w, k % w
    step = math.pi / (h - 1)
    if es.env_density.shape[0] > 1:  # Mitsuba's: bilinear in (u, v), v by its marginal, then u given v
        f = es.env_density
        c00, c10, c01, c11 = f[i, j], f[i, j + 1], f[i + 1, j], f[i + 1, j + 1]
        t = _linear(c00 + c10, c01 + c11, u3)
        a, b = (1.0 - t) * c00 + t * c01, (1.0 - t) * c10 + t * c11
        s = _linear(a, b, u2)
        theta = (i + t) * step
        cos_t, sin_t = math.cos(theta), math.sin(theta)
        pdf = ((1.0 - s) * a + s * b) / (2.0 * math.pi * math.pi * sin_t) if sin_t > 0.0 else 0.0
    else:  # uniform in solid angle within the cell
        s = u2
        c0, c1 = math.cos(i * step), math.cos((i + 1) * step)
        cos_t = c0 - u3 * (c0 - c1)
        theta = math.acos(min(max(cos_t, -1.0), 1.0))
        sin_t = math.sqrt(max(0.0, 1.0 - cos_t * cos_t))
        pdf = es.env_cell_pdf[k]
    phi = 2.0 * math.pi * ((j + s) / w + es.env_shift)
    lx, ly, lz = math.sin(phi) * sin_t, cos_t, -math.cos(phi) * sin_t
    m = es.env_to_world
    dx = m[0, 0] * lx + m[0, 1] * ly + m[0, 2] * lz
    dy = m[1, 0] * lx + m[1, 1] * ly + m[1, 2] * lz
    dz = m[2, 0] * lx + m[2, 1] * ly + m[2, 2] * lz
    r = math.sqrt(dx * dx + dy * dy + dz * dz)
    l0, l1, l2 = _bilinear(es.env_image, j + s, min(theta / step, h - 1.0))
    return dx / r, dy / r, dz / r, pdf, l0, l1, l2
