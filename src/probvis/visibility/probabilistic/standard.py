"""The 2013 paper's standard decomposition: V_A V_B = V_A + V_B + (V̄_A V̄_B - 1)."""
import numpy as np

from .decomposition import MODE_A, MODE_AB_BLOCKED, MODE_B, Decomposition, probabilities, table


def standard(p=(1 / 3, 1 / 3, 1 / 3)):
    d = Decomposition("standard", np.stack([table(lambda a, b: a), table(lambda a, b: b),
                                            table(lambda a, b: (1 - a) * (1 - b) - 1)]),
                      probabilities(p), np.array([MODE_A, MODE_B, MODE_AB_BLOCKED], np.int8),
                      ("V_A/p1", "V_B/p2", "(V̄_A V̄_B - 1)/p3"))
    d.check()
    return d
