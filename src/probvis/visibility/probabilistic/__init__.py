"""Probabilistic visibility (Billen et al. 2013): decompositions of V = V_A V_B evaluated stochastically over the
occlusion map's candidate blockers.

Modules: `decomposition` (the term tables), `standard`, `shifted` and `power` (the decompositions), `mixture`
(the adaptive mixture: per pair the terms that minimise variance x cost), `kernels` (grouping and stochastic
evaluation), `estimator` (the `probvis` estimator).
"""
from .decomposition import Decomposition
from .estimator import DECOMPOSITIONS, GROUPINGS, ProbabilisticVisibility
from .power import power
from .shifted import shifted
from .standard import standard

__all__ = ["DECOMPOSITIONS", "Decomposition", "GROUPINGS", "ProbabilisticVisibility", "power", "shifted", "standard"]
