"""Exact visibility: every shadow segment is tested against the whole scene's BVH (any-hit, early exit), the
segments of one shading point traversed together as a packet.

With `shells`, heavy meshes get conservative shells (`probvis.shells`, a voxel grid each segment walks) that
decide some segments first: one crossing an inner shell is blocked, one missing the outer shells is tested
against the rest of the scene only, and the others against the scene only where they cross the outer shells.
The answer is the same for every segment (tested bit for bit); only the tests made differ."""
import numpy as np

from ..accel import occluded_segments
from ..proxies import MIN_TRIANGLES
from ..shells import shell_memory, shell_tests
from ..transmittance import ExtinctionGrid
from .base import Option, Phase, VisibilityEstimator, VisibilityResult


class ExactVisibility(VisibilityEstimator):
    name = "exact"
    summary = "every shadow segment against the whole scene's BVH (the reference)"
    options = (
        Option("shells", bool, False, "decide segments by conservative shells of heavy meshes first (same image)"),
        Option("min_triangles", int, MIN_TRIANGLES, "with shells: meshes of at least this many triangles get them",
               minimum=4),
        Option("cache", bool, True, "cache shells on disk ($PROBVIS_CACHE_DIR, default ~/.cache/probvis)"),
    )
    phases = (
        Phase("shells", "prepare", "building the shells' voxel grid and the BVH of the rest of the scene (or reading the cache)"),
        Phase("render_kernel", "batch", "with shells: sampling, shell and scene tests and the film, fused"),
    )
    fused_any_hit = True

    def prepare(self, scene, bvh, emitters, settings):
        super().prepare(scene, bvh, emitters, settings)
        self.shells = None
        if self.params.shells:
            with self.timed("shells"):
                self.shells = shell_tests(scene, bvh, self.params.min_triangles, self.params.cache)
            if self.shells.active:
                self.fused_any_hit, self.fused_shade = False, True  # renders through the shell kernel
        self.tests = np.zeros(6, np.int64)

    def evaluate(self, query):
        occluded, n_node, n_tri = occluded_segments(self.bvh, query.origin, query.direction, query.tmax, query.point)
        return VisibilityResult(1.0 - occluded, n_node, n_tri)

    def shade(self, geom, emitters, interactions, cases, keys, cam_node, cam_tri, spp, n_shadow, n_pix,
              first_pixel):
        from .proxy_kernel import shade_proxy

        its, e = interactions, self.scene.n_emitters
        with self.timed("render_kernel"):
            img, m2, counts, n_seg, _, tests = shade_proxy(
                geom, emitters, self.bvh.arrays, self.bvh.arrays, its.triangle, its.position, its.normal,
                its.material, its.albedo, cases, keys, its.emitted, cam_node, cam_tri, spp, n_shadow, n_pix,
                np.ones((n_pix, e)), np.ones((n_pix, e), bool), 0.0, *ExtinctionGrid.none().kernel_args,
                *self.shells.kernel_args)
        self.tests += tests
        return img, m2, counts, n_seg

    def memory_estimate(self, scene, settings, batch_samples):
        return shell_memory(scene, self.params.min_triangles) if self.params.shells else {}

    def memory_bytes(self):
        return {"shells": self.shells.nbytes} if self.shells is not None else {}

    def stats(self):
        out = super().stats()
        if self.shells is not None:
            out.update(self.shells.stats(self.tests))
        return out

