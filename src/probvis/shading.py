"""What the kernel of every render path shares, public for estimators that render through a kernel of their own:
the records it takes and returns, the direct-lighting segments of a shading point, the shadow epsilon and the
per-pixel count slots.

A kernel takes a `ShadingBatch` (a batch of whole pixels' camera samples at their first hits) and returns, as a
`ShadedBatch`, each camera sample's radiance and each pixel's counts; the film turns those into pixels. Per
camera sample it calls `point_samples`, which samples the emitters the estimator's cases leave to be sampled
(Mitsuba's `direct` integrator with `bsdf_samples = 0`: emitter by power, point by area, Lambertian BRDF) and
fills shadow-segment slots with their unoccluded contributions; what the segments' visibility multiplies them by
is the estimator's business.
"""
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .cases import CASE_LIT, CASE_MASK, CASE_PENUMBRA, CASE_UNKNOWN, CASE_VERIFIED
from .emitters import delta_falloff, emitter_irradiance, sample_on_emitter
from .environment import sample_environment
from .rng import uniform
from .scene.scene import EMITTER_AREA, EMITTER_DIRECTIONAL, EMITTER_ENVIRONMENT, RAY_OFFSET

SHADOW_EPSILON = 1e-6  # segments stop this fraction short of the emitter point
N_COUNTS = 5  # per-pixel counts: camera-ray triangle and node tests, shadow triangle and node tests, negatives
CAM_TRI, CAM_NODE, SH_TRI, SH_NODE, NEGATIVE = range(N_COUNTS)


class ShadingBatch(NamedTuple):
    """A batch of whole pixels, `spp` camera samples each, at the camera rays' first hits: camera sample i belongs
    to image pixel `pixel[i // spp]` (row-major). `material` is -1 where nothing is reflected (a miss, the back
    of a one-sided surface); `cases` are the estimator's (`VisibilityEstimator.classify`), all unknown if it does
    not classify."""

    pixel: np.ndarray  # (n_pix,) int64 image pixels of the batch
    spp: int
    shadow_rays: int  # emitter samples per camera sample
    triangle: np.ndarray  # (m,) scene triangle hit, -1 on a miss
    emitted: np.ndarray  # (m, 3) radiance seen directly (an emitter's, the environment's)
    position: np.ndarray  # (m, 3)
    normal: np.ndarray  # (m, 3) shading normal on the camera's side
    material: np.ndarray  # (m,) int32
    albedo: np.ndarray  # (m, 3) diffuse reflectance at the point
    cases: np.ndarray  # (m, emitters) int8 CASE_* per camera sample and emitter
    keys: np.ndarray  # (m,) uint64 rng key of each camera sample
    cam_node: np.ndarray  # (m,) ray-node tests of its camera ray
    cam_tri: np.ndarray  # (m,) ray-triangle tests of its camera ray
    film_xy: np.ndarray  # (m, 2) its position on the film, in pixels from the window's corner

    @property
    def n_pix(self):
        return len(self.pixel)


class ShadedBatch(NamedTuple):
    """What a render path returns for a `ShadingBatch`: the film's input."""

    radiance: np.ndarray  # (m, 3) each camera sample's radiance
    counts: np.ndarray  # (n_pix, N_COUNTS) int64 per pixel: CAM_TRI, CAM_NODE, SH_TRI, SH_NODE, NEGATIVE
    segments: np.ndarray  # (n_pix,) int64 shadow segments made per pixel
    aovs: dict = None  # name -> (n_pix,) per pixel: the estimator's "segment" AOVs (mean over camera samples)


@njit(cache=True, error_model="numpy", inline="always")
def shaded_arrays(batch):
    """Zeroed `ShadedBatch` arrays of a batch: radiance per camera sample, counts and segments per pixel."""
    n_pix = batch.pixel.shape[0]
    return (np.zeros((n_pix * batch.spp, 3)), np.zeros((n_pix, N_COUNTS), np.int64), np.zeros(n_pix, np.int64))


@njit(cache=True, error_model="numpy", inline="always")
def is_sampled(case):
    """Whether an emitter of this occlusion case gets shadow rays (lit ones are integrated, shadowed skipped,
    unless verified)."""
    c = case & CASE_MASK
    return c == CASE_UNKNOWN or c == CASE_PENUMBRA or (case & CASE_VERIFIED) != 0


@njit(cache=True, error_model="numpy", inline="always")
def sampled_share(pmf, cases, i):
    """Total selection probability of the emitters point `i` samples (`cases[i, e]` unknown or penumbra), and
    that emitter's id if there is only one (else -1: a choice is needed)."""
    total = 0.0
    only = -1
    count = 0
    for e in range(pmf.shape[0]):
        if is_sampled(cases[i, e]):
            total += pmf[e]
            only = e
            count += 1
    return total, only if count == 1 else -1


@njit(cache=True, error_model="numpy", inline="always")
def choose_emitter(pmf, cases, i, total, u):
    """An emitter among those point `i` samples, by power, given their `sampled_share` `total` (> 0):
    (emitter id, its selection probability)."""
    target = u * total
    last = -1
    acc = 0.0
    for e in range(pmf.shape[0]):
        if is_sampled(cases[i, e]):
            last = e
            acc += pmf[e]
            if acc > target:
                return e, pmf[e] / total
    return last, pmf[last] / total  # only reached through rounding when u is within an ulp of 1


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy", inline="always")
def emitter_segment(slot, le, scale, rgb, u, es, triangles, fnormals, p, s, gn, eps, contrib, s_org, s_dir,
                     s_emit, active):
    """Fill shadow slot `slot` with a point sampled on emitter `le` (random numbers `u`) seen from shading
    point p (shading normal s, geometric normal gn): segment, contribution `rgb` x `scale` x cos cos / d^2
    (`scale` holds area / (pdf of the emitter x samples x pi)) and the active flag. No branches: the slot is
    written whether or not the emitter point faces p, and `active` says which. Inlined: called, its seventeen
    arguments (arrays and records of arrays) cost three times its arithmetic, 52 against 17 ns a segment."""
    t0 = t1 = t2 = 1.0  # the environment's radiance / pdf of its direction, per channel
    if es.kind[le] == EMITTER_AREA:
        lt, yx, yy, yz = sample_on_emitter(le, es, triangles, u[0], u[1], u[2])
        wx, wy, wz = yx - p[0], yy - p[1], yz - p[2]
        d2 = wx * wx + wy * wy + wz * wz
        # cosines times |w|: their signs need no square root, and cos_x cos_y / d2 = dot_x dot_y / d2^2
        dot_x = s[0] * wx + s[1] * wy + s[2] * wz
        dot_y = -(fnormals[lt, 0] * wx + fnormals[lt, 1] * wy + fnormals[lt, 2] * wz)
    elif es.kind[le] == EMITTER_DIRECTIONAL:  # E cos_x: the segment leaves the scene against the light's travel
        r2 = 2.0 * es.sphere[3]
        yx, yy, yz = p[0] - es.axis[le, 0] * r2, p[1] - es.axis[le, 1] * r2, p[2] - es.axis[le, 2] * r2
        wx, wy, wz = yx - p[0], yy - p[1], yz - p[2]
        d2 = wx * wx + wy * wy + wz * wz
        dot_x = s[0] * wx + s[1] * wy + s[2] * wz
        dot_y = d2 * math.sqrt(d2)  # so that dot_x dot_y / d2^2 = cos_x
    elif es.kind[le] == EMITTER_ENVIRONMENT:  # L(w) cos_x / pdf(w): the segment leaves the scene along w
        dx, dy, dz, pdf, t0, t1, t2 = sample_environment(es, u[0], u[1], u[2])
        inv = 1.0 / pdf if pdf > 0.0 else 0.0
        t0, t1, t2 = t0 * inv, t1 * inv, t2 * inv
        r2 = 2.0 * es.sphere[3]
        yx, yy, yz = p[0] + dx * r2, p[1] + dy * r2, p[2] + dz * r2
        wx, wy, wz = yx - p[0], yy - p[1], yz - p[2]
        d2 = wx * wx + wy * wy + wz * wz
        dot_x = s[0] * wx + s[1] * wy + s[2] * wz
        dot_y = d2 * math.sqrt(d2) if pdf > 0.0 else 0.0
    else:  # a point or spot light: cos_x I / d2 = dot_x |w| / d2^2, times a spot's falloff
        yx, yy, yz = es.position[le, 0], es.position[le, 1], es.position[le, 2]
        wx, wy, wz = yx - p[0], yy - p[1], yz - p[2]
        d2 = wx * wx + wy * wy + wz * wz
        dot_x = s[0] * wx + s[1] * wy + s[2] * wz
        dot_y = math.sqrt(d2) * delta_falloff(es, le, -wx, -wy, -wz)
    g = dot_x * dot_y * scale / (d2 * d2)
    off = eps if gn[0] * wx + gn[1] * wy + gn[2] * wz > 0.0 else -eps
    ox, oy, oz = p[0] + off * gn[0], p[1] + off * gn[1], p[2] + off * gn[2]
    contrib[slot, 0], contrib[slot, 1], contrib[slot, 2] = rgb[0] * g * t0, rgb[1] * g * t1, rgb[2] * g * t2
    s_org[slot, 0], s_org[slot, 1], s_org[slot, 2] = ox, oy, oz
    s_dir[slot, 0], s_dir[slot, 1], s_dir[slot, 2] = yx - ox, yy - oy, yz - oz
    s_emit[slot] = le
    active[slot] = (dot_x > 0.0) & (dot_y > 0.0)


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def point_samples(i, geom, es, batch, base, s_org, s_dir, contrib, s_emit, active, sample, dense):
    """Direct light at camera sample `i` of the `ShadingBatch` (`geom` is the `SceneArrays`, `es` the
    `EmitterArrays`), per emitter as the visibility estimator's `batch.cases` say:

    lit (case 1) emitters are integrated analytically (Lambert's polygon formula, no noise, no rays),
    shadowed (case 2) ones contribute nothing, and the others, verified lit and shadowed ones included, are
    sampled: `batch.shadow_rays` emitter samples (emitter
    by power among the sampled ones, point uniform by area) in slots base..base + shadow_rays - 1. Fills, per
    slot, segment origin and direction, the unoccluded contribution (already divided by pdf and shadow rays), the
    emitter id and the active flag (the other outputs of an inactive slot are meaningless). With `dense` (a
    constant in each caller) only the active samples are kept, in slots base..base + m - 1 (a sample is
    written at base + m and kept by advancing m), and `sample` says which emitter sample (0..shadow_rays - 1)
    each kept slot holds: the staged path keys a segment's random numbers by it (`segments.compact`). Returns
    the analytic radiance and m (0 without `dense`).
    """
    triangles, fnormals, radiance = geom.triangles, geom.face_normals, geom.emitter_radiance
    pmf, area = es.pmf, es.area
    pos, nrm, refl, cases, n_shadow = batch.position, batch.normal, batch.albedo, batch.cases, batch.shadow_rays
    inv_pi = 1.0 / math.pi
    a0 = a1 = a2 = 0.0
    m = 0
    mi = batch.material[i]
    if mi < 0:
        for j in range(n_shadow):
            active[base + j] = False
        return a0, a1, a2, m
    tri = batch.triangle[i]
    p = (pos[i, 0], pos[i, 1], pos[i, 2])
    s = (nrm[i, 0], nrm[i, 1], nrm[i, 2])
    for e in range(pmf.shape[0]):
        if cases[i, e] & CASE_MASK == CASE_LIT:
            f = emitter_irradiance(e, es, triangles, p[0], p[1], p[2], s[0], s[1], s[2]) * inv_pi
            a0 += refl[i, 0] * radiance[e, 0] * f
            a1 += refl[i, 1] * radiance[e, 1] * f
            a2 += refl[i, 2] * radiance[e, 2] * f
    total, only = sampled_share(pmf, cases, i)
    if total <= 0.0:
        for j in range(n_shadow):
            active[base + j] = False
        return a0, a1, a2, m
    gn = (fnormals[tri, 0], fnormals[tri, 1], fnormals[tri, 2])
    eps = RAY_OFFSET * (1.0 + max(abs(p[0]), abs(p[1]), abs(p[2])))
    key = batch.keys[i]
    if only >= 0:  # a single emitter: no choice (its random dimension is simply not drawn)
        only = np.int64(only)  # not typed as the literal -1 it may also be: one compile of emitter_segment
        scale = area[only] * inv_pi / n_shadow
        rgb = (refl[i, 0] * radiance[only, 0], refl[i, 1] * radiance[only, 1], refl[i, 2] * radiance[only, 2])
        for j in range(n_shadow):
            u = (uniform(key, 3 + 4 * j), uniform(key, 4 + 4 * j), uniform(key, 5 + 4 * j))
            slot = base + m if dense else base + j
            emitter_segment(slot, only, scale, rgb, u, es, triangles, fnormals, p, s, gn, eps, contrib, s_org,
                            s_dir, s_emit, active)
            if dense:
                sample[slot] = j
                m += active[slot]
        return a0, a1, a2, m
    for j in range(n_shadow):
        le, p_e = choose_emitter(pmf, cases, i, total, uniform(key, 2 + 4 * j))
        rgb = (refl[i, 0] * radiance[le, 0], refl[i, 1] * radiance[le, 1], refl[i, 2] * radiance[le, 2])
        u = (uniform(key, 3 + 4 * j), uniform(key, 4 + 4 * j), uniform(key, 5 + 4 * j))
        slot = base + m if dense else base + j
        emitter_segment(slot, le, area[le] * inv_pi / (p_e * n_shadow), rgb, u, es, triangles, fnormals, p, s,
                        gn, eps, contrib, s_org, s_dir, s_emit, active)
        if dense:
            sample[slot] = j
            m += active[slot]
    return a0, a1, a2, m


