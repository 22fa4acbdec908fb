"""A voxel-to-voxel visibility cache: the visibility map of NEE++ (Guo, Eisemann and Eisemann, Pacific Graphics
2020). A uniform grid over the scene and, per pair of voxels — the shading point's and the emitter point's —
how many of a pilot's shadow segments between them were unoccluded.

The pilot renders a spread-out subset of the pixels, one camera sample each, through the integrator's own
segments (`Integrator.shadow_query`) with a seed of its own, and traces them exactly.

`CachedVisibility` is the base of the estimators that read it (`nee++`, `cache-cv`): per segment a control
value c and a probability p from the cache, the estimate c + B (V − c) / p with B a coin of probability p.
E = c + p (V − c) / p = V, whatever the cache holds: it only steers how often they trace and what they subtract.
"""
import abc
from dataclasses import dataclass

import numba
import numpy as np

from ..accel import occluded_segments
from ..rng import uniforms
from ..settings import MAX_SEED
from ..shading import ShadedBatch
from ..voxels import grid_placement
from .base import Aov, Option, Phase, RenderPath, VisibilityEstimator, VisibilityResult
from .cache_kernel import CacheArrays, pair_keys, segment_plans, shade_cached

PILOT_SEED = 1 << 40  # added to the render's seed (modulo 2^63): the pilot's camera samples are none of the render's
PILOT_PIXELS_PER_BATCH = 1 << 16


@dataclass
class VisibilityCache:
    """Pilot counts per voxel pair, sorted by pair key (`arrays` for the kernels)."""

    arrays: CacheArrays
    segments: int = 0  # pilot segments traced
    node_tests: int = 0
    triangle_tests: int = 0

    def pair_keys(self, origin, direction):
        return pair_keys(self.arrays, np.ascontiguousarray(origin), np.ascontiguousarray(direction))

    def plans(self, plan, origin, direction):
        """(c, p) of each segment under `plan`."""
        return segment_plans(self.arrays, plan, np.ascontiguousarray(origin), np.ascontiguousarray(direction))

    def nbytes(self):
        a = self.arrays
        return int(a.row.nbytes + a.emitter_voxel.nbytes + a.visible.nbytes + a.total.nbytes)

    def stats(self):
        return {"pairs": int(len(self.arrays.emitter_voxel)), "pilot_segments": self.segments,
                "voxels": self.arrays.dims.tolist(), "pilot_node_tests": self.node_tests,
                "pilot_triangle_tests": self.triangle_tests}


def pilot_pixels(n_pixels, spp, share):
    """A spread-out subset of the image's pixels: one camera sample each, `share` of the render's samples."""
    m = int(min(n_pixels, max(1, round(share * n_pixels * spp))))
    return np.unique(np.linspace(0, n_pixels - 1, m).round().astype(np.int64))


def build_cache(scene, bvh, integrator, settings, resolution, share):
    """The cache of a pilot of `share` of the render's camera samples (with its shadow rays each) over a grid of
    `resolution` voxels along the scene's longest side."""
    lo, hi = bvh.bounds[0, :3], bvh.bounds[0, 3:]  # the root's box: the scene's
    corner, pitch, dims = grid_placement(lo, hi, resolution)
    n_voxels = int(np.prod(dims))
    grid = CacheArrays(np.asarray(corner, np.float64), float(pitch), dims.astype(np.int64),
                       np.zeros(n_voxels + 1, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int64))
    cache = VisibilityCache(grid)
    pixels = pilot_pixels(scene.camera.width * scene.camera.height, settings.spp, share)
    keys, visible = [], []
    per_batch = max(1, PILOT_PIXELS_PER_BATCH // settings.shadow_rays)
    for b0 in range(0, len(pixels), per_batch):
        batch = integrator.shading_batch(pixels[b0:b0 + per_batch], 1, settings.shadow_rays,
                                         (settings.seed + PILOT_SEED) & MAX_SEED)  # a valid seed still
        q = integrator.shadow_query(batch)
        occluded, n_node, n_tri = occluded_segments(bvh, q.origin, q.direction, q.tmax, q.point)
        keys.append(cache.pair_keys(q.origin, q.direction))
        visible.append(1.0 - occluded)
        cache.segments += len(q.tmax)
        cache.node_tests += int(n_node.sum())
        cache.triangle_tests += int(n_tri.sum())
    if keys:
        k, inv = np.unique(np.concatenate(keys), return_inverse=True)
        row = np.searchsorted(k // n_voxels, np.arange(n_voxels + 1)).astype(np.int64)
        unoccluded = np.bincount(inv, np.concatenate(visible), len(k)).astype(np.float64)  # int64 when empty
        cache.arrays = grid._replace(row=row, emitter_voxel=k % n_voxels, visible=unoccluded,
                                     total=np.bincount(inv, minlength=len(k)).astype(np.int64))
    return cache


CACHE_OPTIONS = (
    Option("resolution", int, 16, "the cache's voxels along the scene's longest side", minimum=4, maximum=256),
    Option("pilot", float, 0.05, "the pilot's camera samples (one per pixel, each with the render's shadow rays) "
           "as a share of the render's", minimum=0.001, maximum=1.0),
)


class CachedVisibility(VisibilityEstimator):
    """An estimator c + B (V − c) / p steered by the cache: subclasses declare `name`, `summary`, `options` (with
    `CACHE_OPTIONS`) and implement `plan`."""

    phases = (
        Phase("pilot", "prepare", "the pilot's segments traced exactly into the voxel-pair cache"),
        Phase("render_kernel", "batch", "sampling, each segment's voxel pair in the cache and its coin, the drawn "
              "segments traced, the samples' radiance, fused"),
    )
    aovs = (Aov("traced", "shadow segments traced per camera sample"),)

    @abc.abstractmethod
    def plan(self):
        """The estimator's `CachePlan`: how a segment's c and p follow from its voxel pair's pilot counts."""

    def prepare(self, scene, bvh, emitters, settings, integrator):
        super().prepare(scene, bvh, emitters, settings, integrator)
        with self.timed("pilot"):
            self.cache = build_cache(scene, bvh, integrator, settings, self.params.resolution, self.params.pilot)
        self.segments = self.traced = 0

    def render_path(self):
        return RenderPath.OWN_KERNEL

    def shade(self, batch):
        """The batch through `cache_kernel.shade_cached`: value for value what `evaluate` gives (tested)."""
        with self.timed("render_kernel"):
            radiance, counts, n_seg, traced = shade_cached(self.integrator.scene_arrays, self.emitters.arrays,
                                                           self.bvh.arrays, batch, self.cache.arrays, self.plan(),
                                                           numba.get_num_threads())
        self.segments += int(n_seg.sum())
        self.traced += int(traced.sum())
        return ShadedBatch(radiance, counts, n_seg, {"traced": traced / batch.spp})

    def evaluate(self, query):
        """The staged interface: c + B (V − c) / p per segment, B drawn from the segment's key."""
        n = len(query.tmax)
        c, p = self.cache.plans(self.plan(), query.origin, query.direction)
        idx = np.flatnonzero(uniforms(query.key, 0) < p)
        node_tests = np.zeros(n, np.int64)
        triangle_tests = np.zeros(n, np.int64)
        occluded, node_tests[idx], triangle_tests[idx] = occluded_segments(
            self.bvh, query.origin[idx], query.direction[idx], query.tmax[idx], query.point[idx])
        c[idx] += (1.0 - occluded - c[idx]) / p[idx]
        traced = np.zeros(n)
        traced[idx] = 1.0
        self.segments += n
        self.traced += len(idx)
        return VisibilityResult(c, node_tests, triangle_tests, aovs={"traced": traced})

    def memory_estimate(self, scene, settings, batch_samples):
        """The pilot's segments of one batch, at most a pair entry per pilot segment, and the rows of the grid's
        voxels (at most resolution + 2 along every axis)."""
        n = len(pilot_pixels(scene.camera.width * scene.camera.height, settings.spp, self.params.pilot))
        return {"cache": n * settings.shadow_rays * 24 + 8 * (self.params.resolution + 2) ** 3,
                "pilot": min(n * settings.shadow_rays, PILOT_PIXELS_PER_BATCH) * 160}

    def memory_bytes(self):
        return {"cache": self.cache.nbytes()}

    def stats(self):
        out = super().stats()
        out["cache"] = self.cache.stats()
        out["traced_share"] = self.traced / max(self.segments, 1)
        return out

