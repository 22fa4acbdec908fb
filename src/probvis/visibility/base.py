"""The visibility interface: one call that turns a batch of shadow segments into real-valued visibility.

An estimator may return any real number per segment (probabilistic estimators return negative values);
the integrator multiplies it with the unoccluded contribution, so an estimator is unbiased exactly when
the expectation of its value is the binary visibility of the segment.
"""
import abc
from dataclasses import dataclass

import numpy as np

from ..cases import CASE_LIT, CASE_NAMES, CASE_PENUMBRA, CASE_SHADOWED, CASE_UNKNOWN, N_CASES  # noqa: F401



@dataclass
class ShadingPoints:
    """First hits of the camera samples in a batch; `normal` is the shading normal on the lit side."""

    position: np.ndarray  # (m, 3)
    normal: np.ndarray  # (m, 3)
    triangle: np.ndarray  # (m,) scene triangle id, -1 where the camera ray escaped


@dataclass
class ShadowQuery:
    """Shadow segments origin + t * direction, t in (0, tmax), from shading points to emitter points."""

    origin: np.ndarray  # (n, 3), already offset off the surface
    direction: np.ndarray  # (n, 3), emitter point minus origin
    tmax: np.ndarray  # (n,)
    point: np.ndarray  # (n,) index into `points`
    emitter: np.ndarray  # (n,) emitter id of the sampled point
    key: np.ndarray  # (n,) uint64 rng key, unique per segment, for stochastic estimators
    points: ShadingPoints


@dataclass
class VisibilityResult:
    value: np.ndarray  # (n,) float64, the visibility estimate of each segment
    node_tests: np.ndarray  # (n,) ray-node tests made for the segment
    triangle_tests: np.ndarray  # (n,) ray-triangle tests made for the segment


class VisibilityEstimator(abc.ABC):
    """Subclass, give it a `name`, implement `evaluate`, and register it in `probvis.visibility`."""

    name = "abstract"
    any_hit_only = False  # True if `evaluate` is 1 - `accel.occluded_segments`: the integrator then traces itself

    def prepare(self, scene, bvh, emitters):
        """Build whatever per-scene structure the estimator needs (timed as part of 'build')."""
        self.scene, self.bvh, self.emitters = scene, bvh, emitters

    def classify(self, points: ShadingPoints):
        """Optionally an (m, n_emitters) int8 array of CASE_* per shading point and emitter, computed before
        the batch's shadow segments are made; `evaluate` of the same batch follows. None samples everything."""
        return None

    @abc.abstractmethod
    def evaluate(self, query: ShadowQuery) -> VisibilityResult:
        """Visibility estimates for a batch of segments."""

    def options(self):
        """The estimator's settings, reported in the render stats."""
        return {}

    def stats(self):
        """Estimator-specific measurements accumulated over the render."""
        return {}
