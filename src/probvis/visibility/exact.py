"""Exact visibility: every shadow segment is tested against the whole scene's BVH (any-hit, early exit), the
segments of one shading point traversed together as a packet.

With shells, heavy meshes get conservative shells (`probvis.shells`, a voxel grid each segment walks) that
decide some segments first: one crossing an inner shell is blocked, one missing the outer shells is tested
against the rest of the scene only, and the others against the scene only where they cross the outer shells.
The answer is the same for every segment (tested bit for bit); only the tests made differ. `shells auto` (the
default) gives them only to the closed heavy meshes that a pilot's segments often cross, where an inner shell
blocks segments early; on an open mesh the outer shell alone costs its walk for little, and on a mesh few
segments come near the walk costs more than it saves (`meshes_for_shells`)."""
from typing import NamedTuple

import numba
import numpy as np

from ..accel import occluded_segments
from ..proxies import MIN_TRIANGLES
from ..shading import ShadedBatch
from ..settings import MAX_SEED
from ..shells import (crossing_share, emitter_boxes, heavy_meshes, mesh_closed, overlaps, shell_memory, shell_tests,
                      span)
from ..transmittance import ExtinctionGrid
from .base import Option, Phase, RenderPath, Switch, VisibilityEstimator, VisibilityResult
from .proxy_kernel import N_TESTS, Correction, geometry_tests, shade_proxy

PILOT_SIDE = 32  # `shells auto`'s pilot: shading points along each side of the image,
PILOT_RAYS = 4  # shadow segments from each
PILOT_SALT = 0x5E11  # its camera samples apart from the render's
WARM_UP_MIN_TRIANGLES = 32  # the warm-up scene's scan (80 triangles) and leaves (48) are heavy meshes at this
CROSSING_SHARE = 0.25  # a closed heavy mesh gets shells when at least this share of the pilot's segments cross its box


class ExactVisibility(VisibilityEstimator):
    name = "exact"
    summary = "every shadow segment against the whole scene's BVH (the reference)"
    options = (
        Option("shells", Switch, "auto", "decide segments by conservative shells of heavy meshes first (same image); "
               "auto: of the closed ones that the segments often cross"),
        Option("min_triangles", int, MIN_TRIANGLES, "with shells: meshes of at least this many triangles get them",
               minimum=4, warm_up=WARM_UP_MIN_TRIANGLES),
        Option("cache", bool, True, "cache shells on disk ($PROBVIS_CACHE_DIR, default ~/.cache/probvis)",
               warm_up=False),
    )
    phases = (
        Phase("shells", "prepare", "building the shells' voxel grid and the BVH of the rest of the scene (or reading the cache)"),
        Phase("render_kernel", "batch", "with shells: sampling, shell and scene tests and the film, fused"),
    )

    @classmethod
    def warm_ups(cls, options, largest=None):
        """With no mesh heavy (the fused kernel); if the scene has a mesh of min_triangles and shells are not off,
        also with the warm-up scene's meshes heavy (the survey, shells and their kernel)."""
        run = super().warm_ups(options, largest)[0]
        p = cls.parse_options(options)
        heavy = p["shells"] != "off" and (largest is None or largest >= p["min_triangles"])
        return [{**run, "min_triangles": MIN_TRIANGLES}] + ([run] if heavy else [])

    def prepare(self, scene, bvh, emitters, settings, integrator):
        super().prepare(scene, bvh, emitters, settings, integrator)
        self.shells = None
        if self.params.shells != "off":
            with self.timed("shells"):
                survey = survey_heavy_meshes(scene, integrator, settings, self.params.min_triangles,
                                             self.params.cache)
                shells = shell_tests(scene, bvh, meshes_for_shells(self.params.shells, survey), self.params.cache)
            self.shells = shells if shells.active else None
        self.tests = np.zeros(N_TESTS, np.int64)

    def render_path(self):
        """The integrator's fused kernel; with shells, the proxy kernel with every emitter exact-only."""
        return RenderPath.OWN_KERNEL if self.shells is not None else RenderPath.FUSED_EXACT

    def evaluate(self, query):
        occluded, n_node, n_tri = occluded_segments(self.bvh, query.origin, query.direction, query.tmax, query.point)
        return VisibilityResult(1.0 - occluded, n_node, n_tri)

    def shade(self, batch):
        n_pix, e = len(batch.pixel), self.scene.n_emitters
        with self.timed("render_kernel"):  # every segment exact: the proxy arguments are placeholders
            radiance, counts, n_seg, _, tests = shade_proxy(
                self.integrator.scene_arrays, self.emitters.arrays, self.bvh.arrays, batch, self.bvh.arrays,
                ExtinctionGrid.none().arrays, 0.0, self.shells.arrays, self.shells.rest.arrays,
                Correction(np.ones((n_pix, e)), np.ones((n_pix, e), bool), np.zeros(e)), numba.get_num_threads())
        self.tests += tests
        return ShadedBatch(radiance, counts, n_seg)

    def memory_estimate(self, scene, settings, batch_samples):
        return shell_memory(scene, self.params.min_triangles) if self.params.shells != "off" else {}

    def memory_bytes(self):
        return {"shells": self.shells.nbytes} if self.shells is not None else {}

    def stats(self):
        out = super().stats()
        if self.shells is not None:
            out["tests"] = geometry_tests(self.tests)
            if self.shells.shells is not None:
                out["shells"] = self.shells.report()
        return out


class HeavyMesh(NamedTuple):
    """What `survey_heavy_meshes` learnt of one heavy mesh."""

    shape: object  # its `ShapeInfo`
    crossed: bool  # at least CROSSING_SHARE of the pilot's shadow segments cross its bounds
    solid: bool  # crossed, closed and with no emitter in its bounds: it can get an inner shell


def survey_heavy_meshes(scene, integrator, settings, min_triangles, use_cache, closedness=True):
    """A `HeavyMesh` for each of the scene's heavy meshes (`heavy_meshes`), from a pilot of the render's own
    shadow segments (PILOT_SIDE² shading points, PILOT_RAYS segments each), in stages from the cheapest
    evidence: the share of the segments that cross the mesh's bounds (the shape's box, known from the load),
    then only for a crossed mesh whether it is closed (`judge_solid`; left for later without `closedness`). A
    mesh few segments meet costs the pilot alone."""
    heavy = heavy_meshes(scene, min_triangles)
    if not heavy:
        return []
    cam = scene.camera
    xs = ((np.arange(PILOT_SIDE) + 0.5) * cam.width / PILOT_SIDE).astype(np.int64)
    ys = ((np.arange(PILOT_SIDE) + 0.5) * cam.height / PILOT_SIDE).astype(np.int64)
    pixels = np.unique(ys[:, None] * cam.width + xs[None, :])
    batch = integrator.shading_batch(pixels, 1, PILOT_RAYS, (settings.seed ^ PILOT_SALT) & MAX_SEED)
    q = integrator.shadow_query(batch)
    out = [HeavyMesh(shape, crossing_share(q.origin, q.direction, q.tmax, shape.lo, shape.hi) >= CROSSING_SHARE,
                     False) for shape in heavy]
    return judge_solid(scene, out, use_cache) if closedness else out


def judge_solid(scene, survey, use_cache):
    """The survey with `solid` decided for its crossed meshes: no emitter in their bounds and closed
    (`mesh_closed`: a content hash and a cache read, a few milliseconds for a million triangles)."""
    boxes = emitter_boxes(scene)
    return [m._replace(solid=m.crossed and not overlaps(boxes, m.shape.lo, m.shape.hi)
                       and mesh_closed(span(scene, m.shape), use_cache)) for m in survey]


def meshes_for_shells(setting, survey):
    """The heavy meshes of a survey (`survey_heavy_meshes`) that get shells under `setting`: "on" every one,
    "off" none, "auto" the closed ones (no emitter in their bounds either) that the pilot's segments often
    cross. Shells decide only the segments that pass near their mesh and cost every segment a walk and the
    shell kernel, so a heavy mesh that most segments pass far from (small in a corner of the view) costs more
    than it saves."""
    if setting == "off":
        return []
    return [m.shape for m in survey if setting == "on" or (m.crossed and m.solid)]
