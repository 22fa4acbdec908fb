"""Power decomposition: (V_A + V_B)^n = V_A + V_B + (2^n - 2) V_A V_B for binary values, so
V_A V_B = [(V_A + V_B)^n - V_A - V_B] / (2^n - 2); the third term needs both groups."""
import numpy as np

from .decomposition import MODE_A, MODE_B, MODE_BOTH, Decomposition, probabilities, table


def power(n=8, p=(1 / 3, 1 / 3, 1 / 3)):
    if int(n) != n or n < 2:
        raise ValueError(f"power must be an integer of at least 2, got {n}")
    k = 2.0 ** n - 2.0
    d = Decomposition(f"power-{int(n)}", np.stack([table(lambda a, b: -a / k), table(lambda a, b: -b / k),
                                                   table(lambda a, b: (a + b) ** n / k)]),
                      probabilities(p), np.array([MODE_A, MODE_B, MODE_BOTH], np.int8),
                      ("-V_A/(2^n-2)/p1", "-V_B/(2^n-2)/p2", "(V_A+V_B)^n/(2^n-2)/p3"))
    d.check()
    return d
