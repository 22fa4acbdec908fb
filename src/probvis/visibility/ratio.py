"""The ratio estimator (Heitz, Hill and McGuire, "Combining Analytic Direct Illumination and Stochastic Shadows",
I3D 2018): per shading point and emitter, the analytic unshadowed radiance times the ratio of the stochastic
shadowed and unshadowed estimates from the same samples,

    L = L_analytic · Σ_i w_i V_i / Σ_i w_i    (w_i a segment's unoccluded contribution),

so each segment's value is V_i · L_analytic / Σ_i w_i. A fully lit pair gets L_analytic exactly, without noise;
a fully shadowed one 0. Consistent, not unbiased: the ratio of two estimates is biased at finite samples (the
bias falls as the pair's samples grow). L_analytic is Lambert's polygon formula the renderer's lit pairs use
(its surfaces are Lambertian); an environment emitter has none, and its segments keep V."""
import math
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from ..accel import SHADOW_PACKET, occluded_packet, occluded_segments, packet_starts, packet_work, root_record
from ..color import luminance
from ..emitters import emitter_irradiance
from ..parallel import spread
from ..scene.scene import EMITTER_ENVIRONMENT
from ..shading import (CAM_NODE, CAM_TRI, SH_NODE, SH_TRI, SHADOW_EPSILON, ShadedBatch, point_samples,
                       shaded_arrays)
from .base import Phase, RenderPath, VisibilityEstimator, VisibilityResult

RUNS_PER_BLOCK = 256  # shading points per parallel work item of the staged interface
PIXELS_PER_BLOCK = 4  # pixels per parallel work item of the kernel


class _Points(NamedTuple):
    """What the staged interface's kernel reads of the batch's shading points, and each segment's point."""

    position: np.ndarray
    normal: np.ndarray
    albedo: np.ndarray
    point: np.ndarray  # (n,) each segment's shading point


@njit(cache=True, error_model="numpy", inline="always")
def pair_factor(e, total, es, triangles, radiance, position, normal, albedo, i):
    """L_analytic / Σ w of shading point i and emitter e, whose segments' unoccluded luminance sums to `total`:
    1 for an environment (no analytic light here) and where the sum is 0."""
    if total <= 0.0 or es.kind[e] == EMITTER_ENVIRONMENT:
        return 1.0
    f = emitter_irradiance(e, es, triangles, position[i, 0], position[i, 1], position[i, 2], normal[i, 0],
                           normal[i, 1], normal[i, 2]) / math.pi
    return f * luminance(albedo[i, 0] * radiance[e, 0], albedo[i, 1] * radiance[e, 1],
                         albedo[i, 2] * radiance[e, 2]) / total


@njit(cache=True, parallel=True, error_model="numpy")
def ratio_factors(runs, emitter, weight, points, es, triangles, radiance):
    """Per segment its pair's `pair_factor`; `runs` are the offsets of each shading point's segments."""
    n_runs = runs.shape[0] - 1
    out = np.ones(weight.shape[0])
    n_blocks = (n_runs + RUNS_PER_BLOCK - 1) // RUNS_PER_BLOCK
    for it in prange(n_blocks):
        blk = spread(it, n_blocks)
        total = np.zeros(es.kind.shape[0])
        factor = np.full(es.kind.shape[0], -1.0)  # the pair's factor once computed; -1: not yet
        for r in range(blk * RUNS_PER_BLOCK, min(n_runs, (blk + 1) * RUNS_PER_BLOCK)):
            a, b = runs[r], runs[r + 1]
            for k in range(a, b):
                total[emitter[k]] += weight[k]
            for k in range(a, b):
                e = emitter[k]
                if factor[e] < 0.0:
                    factor[e] = pair_factor(e, total[e], es, triangles, radiance, points.position, points.normal,
                                            points.albedo, points.point[a])
                out[k] = factor[e]
            for k in range(a, b):
                total[emitter[k]] = 0.0
                factor[emitter[k]] = -1.0
    return out


@njit(cache=True, parallel=True, error_model="numpy")
def shade_ratio(geom, es, bvh, batch):
    """`ShadedBatch` arrays of a `ShadingBatch` with the ratio estimator: every segment traced, its visibility
    times its pair's `pair_factor` — value for value `ratio_factors` on the staged path."""
    root2 = root_record(bvh.root)
    spp, n_shadow = batch.spp, batch.shadow_rays
    radiance, counts, n_seg = shaded_arrays(batch)
    n_pix = counts.shape[0]
    n_blocks = (n_pix + PIXELS_PER_BLOCK - 1) // PIXELS_PER_BLOCK
    for it in prange(n_blocks):
        blk = spread(it, n_blocks)
        org, dirs, contrib = np.empty((n_shadow, 3)), np.empty((n_shadow, 3)), np.empty((n_shadow, 3))
        s_emit, sample = np.empty(n_shadow, np.int32), np.empty(n_shadow, np.int64)
        active = np.empty(n_shadow, np.bool_)
        tmin = np.zeros(n_shadow)
        tmax = np.full(n_shadow, 1.0 - SHADOW_EPSILON)
        occ = np.empty(n_shadow, np.bool_)
        sh_node = np.empty(n_shadow, np.int32)
        sh_tri = np.empty(n_shadow, np.int32)
        work = packet_work(bvh.stack_depth)
        total = np.zeros(es.kind.shape[0])
        factor = np.full(es.kind.shape[0], -1.0)
        for px in range(blk * PIXELS_PER_BLOCK, min(n_pix, (blk + 1) * PIXELS_PER_BLOCK)):
            for s in range(spp):
                i = px * spp + s
                counts[px, CAM_TRI] += batch.cam_tri[i]
                counts[px, CAM_NODE] += batch.cam_node[i]
                a0, a1, a2, m = point_samples(i, geom, es, batch, 0, org, dirs, contrib, s_emit, active, sample, True)
                for lo in range(0, m, SHADOW_PACKET):
                    occluded_packet(bvh, root2, org, dirs, tmin, tmax, lo, min(SHADOW_PACKET, m - lo), work, occ,
                                    sh_node, sh_tri)
                for k in range(m):
                    total[s_emit[k]] += luminance(contrib[k, 0], contrib[k, 1], contrib[k, 2])
                l0, l1, l2 = batch.emitted[i, 0] + a0, batch.emitted[i, 1] + a1, batch.emitted[i, 2] + a2
                for k in range(m):
                    e = s_emit[k]
                    if factor[e] < 0.0:
                        factor[e] = pair_factor(e, total[e], es, geom.triangles, geom.emitter_radiance,
                                                batch.position, batch.normal, batch.albedo, i)
                    v = (1.0 - np.float64(occ[k])) * factor[e]
                    l0 += contrib[k, 0] * v
                    l1 += contrib[k, 1] * v
                    l2 += contrib[k, 2] * v
                    counts[px, SH_TRI] += sh_tri[k]
                    counts[px, SH_NODE] += sh_node[k]
                for k in range(m):
                    total[s_emit[k]] = 0.0
                    factor[s_emit[k]] = -1.0
                n_seg[px] += m
                radiance[i, 0], radiance[i, 1], radiance[i, 2] = l0, l1, l2
    return radiance, counts, n_seg


class RatioVisibility(VisibilityEstimator):
    name = "ratio"
    summary = ("Heitz et al.'s ratio estimator: analytic unshadowed light times shadowed / unshadowed estimates "
               "of each pair (consistent, biased)")
    phases = (Phase("render_kernel", "batch", "sampling, every segment traced, each pair's analytic light and "
                    "ratio, the samples' radiance, fused"),)
    unbiased = False

    def render_path(self):
        return RenderPath.OWN_KERNEL

    def shade(self, batch):
        with self.timed("render_kernel"):
            return ShadedBatch(*shade_ratio(self.integrator.scene_arrays, self.emitters.arrays, self.bvh.arrays,
                                            batch))

    def classify(self, points):
        """Keeps the batch's shading points for the staged interface's `evaluate`; every pair is sampled."""
        self.points = points
        return None

    def evaluate(self, query):
        """The staged interface: every segment traced, times its pair's factor."""
        occluded, n_node, n_tri = occluded_segments(self.bvh, query.origin, query.direction, query.tmax, query.point)
        geom = self.integrator.scene_arrays
        factor = ratio_factors(packet_starts(query.point, len(query.point) + 1), query.emitter, query.weight,
                               _Points(self.points.position, self.points.normal, self.points.albedo, query.point),
                               self.emitters.arrays, geom.triangles, geom.emitter_radiance)
        return VisibilityResult((1.0 - occluded) * factor, n_node, n_tri)
