"""Shifted decomposition: (V_A - α) + (V_B - β) + (V̄_A V̄_B - γ) with α + β + γ = 1. With α = β = γ = 1/3 and
p = 1/3 each this is the 2013 paper's "alternative decomposition", of variance 2 in every configuration."""
import numpy as np

from .decomposition import MODE_A, MODE_AB_BLOCKED, MODE_B, Decomposition, probabilities, table

MAX_SHIFT = 1e6


def shifted(p=(1 / 3, 1 / 3, 1 / 3), shifts=(1 / 3, 1 / 3, 1 / 3)):
    a, b, g = (float(x) for x in shifts)
    if len(shifts) != 3 or not np.isclose(a + b + g, 1.0) or not max(abs(a), abs(b), abs(g)) <= MAX_SHIFT:
        raise ValueError(f"shifts must be three numbers summing to 1, each within ±{MAX_SHIFT:g} (a term's "
                         f"variance grows with its shift's square), got {list(shifts)}")
    if a + b + g != 1.0:  # a sum within rounding of 1 (0.3333333 three times) made exact: the terms must sum to
        g = 1.0 - a - b  # V_A V_B (the default thirds already sum to 1 exactly)
    d = Decomposition("shifted", np.stack([table(lambda x, y: x - a), table(lambda x, y: y - b),
                                           table(lambda x, y: (1 - x) * (1 - y) - g)]),
                      probabilities(p), np.array([MODE_A, MODE_B, MODE_AB_BLOCKED], np.int8),
                      ("(V_A-α)/p1", "(V_B-β)/p2", "(V̄_A V̄_B-γ)/p3"))
    d.check()
    return d
