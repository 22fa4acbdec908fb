"""Exact visibility: every shadow segment is tested against the whole scene's BVH (any-hit, early exit), the
segments of one shading point traversed together as a packet."""
from ..accel import occluded_segments
from .base import VisibilityEstimator, VisibilityResult


class ExactVisibility(VisibilityEstimator):
    name = "exact"
    summary = "every shadow segment against the whole scene's BVH (the reference)"
    fused_any_hit = True

    def evaluate(self, query):
        occluded, n_node, n_tri = occluded_segments(self.bvh, query.origin, query.direction, query.tmax, query.point)
        return VisibilityResult(1.0 - occluded, n_node, n_tri)
