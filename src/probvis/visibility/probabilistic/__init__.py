"""Probabilistic visibility (Billen et al. 2013): decompositions of V = V_A V_B evaluated stochastically over the
occlusion map's candidate blockers.

Modules: `decomposition` (the term tables), `standard`, `shifted` and `power` (the decompositions), `mixture`
(the adaptive mixture: per pair the terms that minimise variance x cost), `kernels` (grouping and stochastic
evaluation), `estimator` (the `probvis` estimator).
"""
from .decomposition import Decomposition
from .power import power
from .shifted import shifted
from .standard import standard


def __getattr__(name):
    """The estimator, imported when first asked for: the occlusion map's kernel imports this package's term
    tables, and the estimator subclasses the occlusion map's."""
    if name in ("DECOMPOSITIONS", "GROUPINGS", "ProbabilisticVisibility"):
        from . import estimator

        return getattr(estimator, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["DECOMPOSITIONS", "Decomposition", "GROUPINGS", "ProbabilisticVisibility", "power", "shifted", "standard"]
