"""Visibility estimators behind one interface; `make_estimator(name, **options)` builds one by name."""
from ..errors import ProbvisError
from .base import (CASE_LIT, CASE_NAMES, CASE_PENUMBRA, CASE_SHADOWED, CASE_UNKNOWN, N_CASES, ShadingPoints,
                   ShadowQuery, VisibilityEstimator, VisibilityResult)
from .exact import ExactVisibility
from .occlusion_map import OcclusionMapVisibility
from .probvis import ProbvisVisibility

ESTIMATORS = {cls.name: cls for cls in (ExactVisibility, OcclusionMapVisibility, ProbvisVisibility)}


def make_estimator(name, **options):
    if isinstance(name, VisibilityEstimator):
        return name
    if name not in ESTIMATORS:
        raise ProbvisError(f"unknown visibility '{name}' (available: {', '.join(ESTIMATORS)})")
    try:
        return ESTIMATORS[name](**options)
    except TypeError as exc:
        raise ProbvisError(f"bad options for visibility '{name}': {exc}") from None


__all__ = ["CASE_LIT", "CASE_NAMES", "CASE_PENUMBRA", "CASE_SHADOWED", "CASE_UNKNOWN", "ESTIMATORS", "N_CASES", "ShadingPoints", "ShadowQuery", "VisibilityEstimator", "VisibilityResult",
           "make_estimator"]
