"""Probabilistic visibility: decompositions of V = V_A V_B evaluated over the occlusion map's blockers."""
from .decomposition import Decomposition
from .estimator import ESTIMATOR_NAMES, GROUPINGS, ProbvisVisibility
from .power import power
from .shifted import shifted
from .standard import standard

__all__ = ["Decomposition", "ESTIMATOR_NAMES", "GROUPINGS", "ProbvisVisibility", "power", "shifted", "standard"]
