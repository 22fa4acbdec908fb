"""The ratio estimator (Heitz, Hill and McGuire, "Combining Analytic Direct Illumination and Stochastic Shadows",
I3D 2018): per pixel, the analytic unshadowed radiance times the ratio of the stochastic shadowed and unshadowed
estimates from the same samples,

    L = L_analytic · Σ_i w_i V_i / Σ_i w_i    (w_i a segment's unoccluded contribution),

the sums over all of the pixel's camera samples and their segments, L_analytic the mean of its samples'; so each
segment's value is V_i · Σ_s L_analytic(s) / Σ_i w_i. A fully lit pixel gets its analytic light exactly, without
noise; a fully shadowed one 0. Consistent, not unbiased: the ratio of two estimates is biased at finite samples,
and the bias falls as the pixel's samples grow, in camera samples as in shadow rays. (A ratio per camera sample
stays biased however many camera samples a pixel takes: a sample whose every emitter sample fell on a light that
cannot reach it — a spot light aimed elsewhere — had no ratio to form, and one shadow ray gave L_analytic · V of
a light chosen by power, not by its contribution.) L_analytic is Lambert's polygon formula the renderer's lit
pairs use (its surfaces are Lambertian), summed over the emitters: the integrator chooses an emitter per sample,
and a ratio per emitter would lose every emitter a pixel's samples happened not to choose. An environment has no
analytic light here: its part of L_analytic is its samples' own estimate Σ_env w_i, so that it cancels where
everything is visible and the other emitters' light is kept even when only the environment was sampled."""
import math
from typing import NamedTuple

import numba
import numpy as np
from numba import njit, prange

from ..accel import SHADOW_PACKET, occluded_packet, occluded_segments, packet_work, root_record
from ..color import luminance
from ..emitters import emitter_irradiance
from ..scene.scene import EMITTER_ENVIRONMENT
from ..shading import (CAM_NODE, CAM_TRI, SH_NODE, SH_TRI, SHADOW_EPSILON, ShadedBatch, point_samples,
                       shaded_arrays)
from .base import Phase, RenderPath, VisibilityEstimator, VisibilityResult

PIXELS_PER_BLOCK = 4  # pixels per parallel work item of the kernel


class _Points(NamedTuple):
    """What the staged interface's kernel reads of the batch's shading points."""

    position: np.ndarray
    normal: np.ndarray
    albedo: np.ndarray


@njit(cache=True, error_model="numpy", inline="always")
def analytic_light(es, triangles, radiance, position, normal, albedo, i):
    """L_analytic of shading point i (luminance), of the emitters other than environments."""
    light = 0.0
    for e in range(es.kind.shape[0]):
        if es.kind[e] != EMITTER_ENVIRONMENT:
            f = emitter_irradiance(e, es, triangles, position[i, 0], position[i, 1], position[i, 2], normal[i, 0],
                                   normal[i, 1], normal[i, 2]) / math.pi
            light += f * luminance(albedo[i, 0] * radiance[e, 0], albedo[i, 1] * radiance[e, 1],
                                   albedo[i, 2] * radiance[e, 2])
    return light


@njit(cache=True, error_model="numpy", inline="always")
def pixel_factor(total, env, light):
    """Σ_s L_analytic(s) / Σ w of a pixel whose segments' unoccluded luminance sums to `total`, `env` of it from
    environments (which stands for their analytic light), its shaded samples' `analytic_light` to `light`: 1
    where the pixel has no segment (nothing to scale)."""
    return (light + env) / total if total > 0.0 else 1.0


@njit(cache=True, error_model="numpy")
def ratio_factors(point, spp, emitter, weight, points, shaded, es, triangles, radiance):
    """Per segment its pixel's `pixel_factor`; segments in the order of their shading point (`point`), camera
    sample i of pixel i // spp, `shaded` the samples that reflect light. Sums in the fused kernel's order."""
    n_pix = shaded.shape[0] // spp
    total, env, light = np.zeros(n_pix), np.zeros(n_pix), np.zeros(n_pix)
    for k in range(point.shape[0]):
        px = point[k] // spp
        total[px] += weight[k]
        if es.kind[emitter[k]] == EMITTER_ENVIRONMENT:
            env[px] += weight[k]
    for i in range(shaded.shape[0]):
        if shaded[i]:
            light[i // spp] += analytic_light(es, triangles, radiance, points.position, points.normal, points.albedo,
                                              i)
    out = np.empty(point.shape[0])
    for k in range(point.shape[0]):
        px = point[k] // spp
        out[k] = pixel_factor(total[px], env[px], light[px])
    return out


@njit(cache=True, parallel=True, error_model="numpy")
def shade_ratio(geom, es, bvh, batch, threads):
    """`ShadedBatch` arrays of a `ShadingBatch` with the ratio estimator: every segment traced, its visibility
    times its pixel's `pixel_factor`, as `ratio_factors` on the staged path (to rounding: here each sample's sum
    of unoccluded contributions is scaled, there each segment). `threads` is the thread budget."""
    root2 = root_record(bvh.root)
    spp, n_shadow = batch.spp, batch.shadow_rays
    radiance, counts, n_seg = shaded_arrays(batch)
    n_pix = counts.shape[0]
    n_blocks = (n_pix + PIXELS_PER_BLOCK - 1) // PIXELS_PER_BLOCK
    lanes = min(threads, n_blocks)
    for lane in prange(lanes):  # one lane of blocks per thread (see `parallel`)
        for blk in range(lane, n_blocks, lanes):
            org, dirs, contrib = np.empty((n_shadow, 3)), np.empty((n_shadow, 3)), np.empty((n_shadow, 3))
            s_emit, sample = np.empty(n_shadow, np.int32), np.empty(n_shadow, np.int64)
            active = np.empty(n_shadow, np.bool_)
            tmin = np.zeros(n_shadow)
            tmax = np.full(n_shadow, 1.0 - SHADOW_EPSILON)
            occ = np.empty(n_shadow, np.bool_)
            sh_node = np.empty(n_shadow, np.int32)
            sh_tri = np.empty(n_shadow, np.int32)
            work = packet_work(bvh.stack_depth)
            seen = np.empty((spp, 3))  # each sample's unoccluded contributions, scaled once its pixel's are in
            for px in range(blk * PIXELS_PER_BLOCK, min(n_pix, (blk + 1) * PIXELS_PER_BLOCK)):
                total = env = light = 0.0
                for s in range(spp):
                    i = px * spp + s
                    counts[px, CAM_TRI] += batch.cam_tri[i]
                    counts[px, CAM_NODE] += batch.cam_node[i]
                    a0, a1, a2, m = point_samples(i, geom, es, batch, 0, org, dirs, contrib, s_emit, active, sample,
                                                  True)
                    for lo in range(0, m, SHADOW_PACKET):
                        occluded_packet(bvh, root2, org, dirs, tmin, tmax, lo, min(SHADOW_PACKET, m - lo), work, occ,
                                        sh_node, sh_tri)
                    u0 = u1 = u2 = 0.0
                    for k in range(m):
                        w = luminance(contrib[k, 0], contrib[k, 1], contrib[k, 2])
                        total += w
                        if es.kind[s_emit[k]] == EMITTER_ENVIRONMENT:
                            env += w
                        v = 1.0 - np.float64(occ[k])
                        u0 += contrib[k, 0] * v
                        u1 += contrib[k, 1] * v
                        u2 += contrib[k, 2] * v
                        counts[px, SH_TRI] += sh_tri[k]
                        counts[px, SH_NODE] += sh_node[k]
                    if batch.material[i] >= 0:
                        light += analytic_light(es, geom.triangles, geom.emitter_radiance, batch.position,
                                                batch.normal, batch.albedo, i)
                    n_seg[px] += m
                    seen[s, 0], seen[s, 1], seen[s, 2] = u0, u1, u2
                    radiance[i, 0] = batch.emitted[i, 0] + a0
                    radiance[i, 1] = batch.emitted[i, 1] + a1
                    radiance[i, 2] = batch.emitted[i, 2] + a2
                f = pixel_factor(total, env, light)
                for s in range(spp):
                    i = px * spp + s
                    radiance[i, 0] += seen[s, 0] * f
                    radiance[i, 1] += seen[s, 1] * f
                    radiance[i, 2] += seen[s, 2] * f
    return radiance, counts, n_seg


class RatioVisibility(VisibilityEstimator):
    name = "ratio"
    summary = ("Heitz et al.'s ratio estimator: analytic unshadowed light times shadowed / unshadowed estimates "
               "of each pixel (consistent, biased)")
    phases = (Phase("render_kernel", "batch", "sampling, every segment traced, each pixel's analytic light and "
                    "ratio, the samples' radiance, fused"),)
    unbiased = False
    independent_samples = False  # a pixel's samples share its factor

    def render_path(self):
        return RenderPath.OWN_KERNEL

    def shade(self, batch):
        with self.timed("render_kernel"):
            return ShadedBatch(*shade_ratio(self.integrator.scene_arrays, self.emitters.arrays, self.bvh.arrays,
                                            batch, numba.get_num_threads()))

    def classify(self, points):
        """Keeps the batch's shading points for the staged interface's `evaluate`; every pair is sampled."""
        self.points = points
        return None

    def evaluate(self, query):
        """The staged interface: every segment traced, times its pixel's factor."""
        occluded, n_node, n_tri = occluded_segments(self.bvh, query.origin, query.direction, query.tmax, query.point)
        geom = self.integrator.scene_arrays
        factor = ratio_factors(query.point, self.render_settings.spp, query.emitter, query.weight,
                               _Points(self.points.position, self.points.normal, self.points.albedo),
                               self.points.triangle >= 0, self.emitters.arrays, geom.triangles,
                               geom.emitter_radiance)
        return VisibilityResult((1.0 - occluded) * factor, n_node, n_tri)
