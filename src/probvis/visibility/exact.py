"""Exact visibility: every shadow segment is tested against the whole scene's BVH (any-hit, early exit)."""
import numpy as np

from ..accel import any_hit
from .base import VisibilityEstimator, VisibilityResult


class ExactVisibility(VisibilityEstimator):
    name = "exact"

    def evaluate(self, query):
        tmin = np.zeros(len(query.tmax))
        occluded, n_node, n_tri = any_hit(self.bvh.arrays, query.origin, query.direction, tmin, query.tmax)
        return VisibilityResult(1.0 - occluded, n_node, n_tri)
