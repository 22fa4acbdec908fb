"""Decompositions of V = V_A V_B into three stochastically chosen terms.

Term i is chosen with probability p_i and returns f_i(V_A, V_B) / p_i; the estimate is unbiased when
sum_i f_i = V_A V_B for all four binary configurations. Each term says which groups it must test (`mode`):
only A, only B, A and then B only if A blocks (the complement product), both, or both exactly (A, then B
only if A is visible). The same tables drive the renderer's kernel and `probvis tables`.
"""
from dataclasses import dataclass

import numpy as np

MODE_A, MODE_B, MODE_AB_BLOCKED, MODE_BOTH, MODE_EXACT = 0, 1, 2, 3, 4
CONFIGS = ((0, 0), (0, 1), (1, 0), (1, 1))


@dataclass
class Decomposition:
    """`f[i]` is a 2 x 2 table f_i(V_A, V_B); `p[i]` its selection probability; `mode[i]` its tests."""

    name: str
    f: np.ndarray  # (3, 2, 2)
    p: np.ndarray  # (3,)
    mode: np.ndarray  # (3,) int8
    labels: tuple = ("", "", "")

    def values(self, va, vb):
        """The stochastic value of each term in configuration (va, vb): f_i / p_i (0 where p_i = 0)."""
        return np.array([self.f[i, va, vb] / self.p[i] if self.p[i] > 0 else 0.0 for i in range(3)])

    def expectation(self, va, vb):
        return float(sum(self.p[i] * self.values(va, vb)[i] for i in range(3)))

    def variance(self, va, vb):
        v = self.values(va, vb)
        return float(np.sum(self.p * v * v) - self.expectation(va, vb) ** 2)

    def coefficients(self):
        """(3, 4) bilinear coefficients (a, b, c, d) of f_i / p_i = a + b V_A + c V_B + d V_A V_B, valid for
        stochastic (non-binary) estimates of V_A and V_B too, as recursive evaluation needs."""
        out = np.zeros((3, 4))
        for i in range(3):
            if self.p[i] <= 0:
                continue
            g = self.f[i] / self.p[i]
            out[i] = g[0, 0], g[1, 0] - g[0, 0], g[0, 1] - g[0, 0], g[1, 1] - g[1, 0] - g[0, 1] + g[0, 0]
        return out

    def reach(self, levels, cells):
        """The largest |estimate| of `levels` recursive splits in each of `cells` multiplied cells: per level, the
        bilinear terms at the corners of the range of their inputs (binary at the leaves); cells multiply."""
        coef, lo, hi = self.coefficients(), 0.0, 1.0
        with np.errstate(over="ignore", invalid="ignore"):  # beyond a double: inf (or NaN), which callers refuse
            for _ in range(levels):
                v = [a + b * x + c * y + d * x * y for a, b, c, d in coef for x in (lo, hi) for y in (lo, hi)]
                lo, hi = min(v), max(v)
            reach = float(np.float64(max(-lo, hi)) ** cells)
        return reach if reach == reach else np.inf

    def check(self):
        for va, vb in CONFIGS:
            if not np.isclose(self.f[:, va, vb].sum(), va * vb, atol=1e-12):
                raise ValueError(f"{self.name}: terms do not sum to V_A V_B at ({va}, {vb})")

    def rows(self):
        """The slide-style table: per configuration the exact values, each term's value and the variance."""
        return [{"VA": va, "VB": vb, "product": va * vb, "values": self.values(va, vb).tolist(),
                 "variance": self.variance(va, vb)} for va, vb in CONFIGS]


def table(fn):
    """A 2 x 2 table from a function of (V_A, V_B)."""
    return np.array([[fn(0, 0), fn(0, 1)], [fn(1, 0), fn(1, 1)]], dtype=float)


MIN_PROBABILITY = 1e-6  # a term's 1/p weight stays within 1e6 (a subnormal p made it infinite)


def probabilities(p):
    p = np.asarray(p, dtype=float)
    if p.shape != (3,) or np.any(~np.isfinite(p)):
        raise ValueError(f"probabilities must be three finite numbers, got {p.tolist()}")
    if np.any(p <= 0):
        raise ValueError(f"probabilities must each be positive, got {p.tolist()} (a term chosen with probability 0 "
                         "is never evaluated: its share of V_A V_B would be lost)")
    if not np.isclose(p.sum(), 1.0):
        raise ValueError(f"probabilities must sum to 1, got {p.tolist()} (sum {p.sum():g})")
    if np.any(p < MIN_PROBABILITY):
        raise ValueError(f"probabilities must each be at least {MIN_PROBABILITY:g}, got {p.tolist()} (a term's "
                         f"estimate is weighted by 1/p: a rarer term makes the variance unbounded in practice)")
    return p / p.sum()
