"""The ratio estimator (Heitz, Hill and McGuire, "Combining Analytic Direct Illumination and Stochastic Shadows",
I3D 2018): per shading point, the analytic unshadowed radiance times the ratio of the stochastic shadowed and
unshadowed estimates from the same samples,

    L = L_analytic · Σ_i w_i V_i / Σ_i w_i    (w_i a segment's unoccluded contribution),

so each segment's value is V_i · L_analytic / Σ_i w_i. A fully lit point gets L_analytic exactly, without
noise; a fully shadowed one 0. Consistent, not unbiased: the ratio of two estimates is biased at finite samples
(the bias falls as the samples grow). L_analytic is Lambert's polygon formula the renderer's lit pairs use (its
surfaces are Lambertian), summed over the emitters: the integrator chooses an emitter per sample, and a ratio per
emitter would lose every emitter a camera sample happened not to choose. An environment has no analytic light
here: its part of L_analytic is its samples' own estimate Σ_env w_i, so that it cancels where everything is
visible and the other emitters' light is kept even when only the environment was sampled."""
import math
from typing import NamedTuple

import numba
import numpy as np
from numba import njit, prange

from ..accel import SHADOW_PACKET, occluded_packet, occluded_segments, packet_starts, packet_work, root_record
from ..color import luminance
from ..emitters import emitter_irradiance
from ..scene.scene import EMITTER_ENVIRONMENT
from ..shading import (CAM_NODE, CAM_TRI, SH_NODE, SH_TRI, SHADOW_EPSILON, ShadedBatch, point_samples,
                       shaded_arrays)
from .base import Phase, RenderPath, VisibilityEstimator, VisibilityResult

PIXELS_PER_BLOCK = 4  # pixels per parallel work item of the kernel


class _Points(NamedTuple):
    """What the staged interface's kernel reads of the batch's shading points, and each segment's point."""

    position: np.ndarray
    normal: np.ndarray
    albedo: np.ndarray
    point: np.ndarray  # (n,) each segment's shading point


@njit(cache=True, error_model="numpy", inline="always")
def point_factor(total, env, es, triangles, radiance, position, normal, albedo, i):
    """L_analytic / Σ w of shading point i, whose segments' unoccluded luminance sums to `total`, `env` of it
    from environments (which stands for their analytic light): 1 where the sum is 0."""
    if total <= 0.0:
        return 1.0
    light = env
    for e in range(es.kind.shape[0]):
        if es.kind[e] != EMITTER_ENVIRONMENT:
            f = emitter_irradiance(e, es, triangles, position[i, 0], position[i, 1], position[i, 2], normal[i, 0],
                                   normal[i, 1], normal[i, 2]) / math.pi
            light += f * luminance(albedo[i, 0] * radiance[e, 0], albedo[i, 1] * radiance[e, 1],
                                   albedo[i, 2] * radiance[e, 2])
    return light / total


@njit(cache=True, parallel=True, error_model="numpy")
def ratio_factors(runs, emitter, weight, points, es, triangles, radiance):
    """Per segment its shading point's `point_factor`; `runs` are the offsets of each shading point's segments."""
    n_runs = runs.shape[0] - 1
    out = np.ones(weight.shape[0])
    for r in prange(n_runs):
        a, b = runs[r], runs[r + 1]
        total = env = 0.0
        for k in range(a, b):
            total += weight[k]
            if es.kind[emitter[k]] == EMITTER_ENVIRONMENT:
                env += weight[k]
        f = point_factor(total, env, es, triangles, radiance, points.position, points.normal, points.albedo,
                         points.point[a])
        for k in range(a, b):
            out[k] = f
    return out


@njit(cache=True, parallel=True, error_model="numpy")
def shade_ratio(geom, es, bvh, batch, threads):
    """`ShadedBatch` arrays of a `ShadingBatch` with the ratio estimator: every segment traced, its visibility
    times its point's `point_factor` — value for value `ratio_factors` on the staged path. `threads` is the
    thread budget."""
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
            for px in range(blk * PIXELS_PER_BLOCK, min(n_pix, (blk + 1) * PIXELS_PER_BLOCK)):
                for s in range(spp):
                    i = px * spp + s
                    counts[px, CAM_TRI] += batch.cam_tri[i]
                    counts[px, CAM_NODE] += batch.cam_node[i]
                    a0, a1, a2, m = point_samples(i, geom, es, batch, 0, org, dirs, contrib, s_emit, active, sample,
                                                  True)
                    for lo in range(0, m, SHADOW_PACKET):
                        occluded_packet(bvh, root2, org, dirs, tmin, tmax, lo, min(SHADOW_PACKET, m - lo), work, occ,
                                        sh_node, sh_tri)
                    total = env = 0.0
                    for k in range(m):
                        w = luminance(contrib[k, 0], contrib[k, 1], contrib[k, 2])
                        total += w
                        if es.kind[s_emit[k]] == EMITTER_ENVIRONMENT:
                            env += w
                    f = point_factor(total, env, es, geom.triangles, geom.emitter_radiance, batch.position,
                                     batch.normal, batch.albedo, i) if m > 0 else 1.0
                    l0, l1, l2 = batch.emitted[i, 0] + a0, batch.emitted[i, 1] + a1, batch.emitted[i, 2] + a2
                    for k in range(m):
                        v = (1.0 - np.float64(occ[k])) * f
                        l0 += contrib[k, 0] * v
                        l1 += contrib[k, 1] * v
                        l2 += contrib[k, 2] * v
                        counts[px, SH_TRI] += sh_tri[k]
                        counts[px, SH_NODE] += sh_node[k]
                    n_seg[px] += m
                    radiance[i, 0], radiance[i, 1], radiance[i, 2] = l0, l1, l2
    return radiance, counts, n_seg


class RatioVisibility(VisibilityEstimator):
    name = "ratio"
    summary = ("Heitz et al.'s ratio estimator: analytic unshadowed light times shadowed / unshadowed estimates "
               "of each shading point (consistent, biased)")
    phases = (Phase("render_kernel", "batch", "sampling, every segment traced, each point's analytic light and "
                    "ratio, the samples' radiance, fused"),)
    unbiased = False

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
        """The staged interface: every segment traced, times its point's factor."""
        occluded, n_node, n_tri = occluded_segments(self.bvh, query.origin, query.direction, query.tmax, query.point)
        geom = self.integrator.scene_arrays
        factor = ratio_factors(packet_starts(query.point, len(query.point) + 1), query.emitter, query.weight,
                               _Points(self.points.position, self.points.normal, self.points.albedo, query.point),
                               self.emitters.arrays, geom.triangles, geom.emitter_radiance)
        return VisibilityResult((1.0 - occluded) * factor, n_node, n_tri)
