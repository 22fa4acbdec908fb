"""Emitter sampling: the alias table's exact distribution, and points uniform by area on a mesh emitter."""
import numpy as np
import pytest
from numba import njit

from probvis.alias import alias_table
from probvis.emitters import EmitterArrays, sample_on_emitter
from probvis.environment import environment_arrays


def alias_distribution(prob, alias):
    """Exact probability of each index under the table: column k (probability 1/n) keeps k with prob[k] and
    gives alias[k] the rest."""
    n = len(prob)
    p = prob / n
    np.add.at(p, alias, (1.0 - prob) / n)
    return p


@pytest.mark.parametrize("weights", [
    [1.0], [1.0, 1.0], [3.0, 1.0], [0.0, 2.0, 0.0, 5.0], [1e-12, 1.0, 1e12],
    *np.random.default_rng(7).gamma(0.3, size=(8, 37)).tolist(),
])
def test_alias_table_enumerates_to_the_weights(weights):
    w = np.array(weights)
    prob, alias = alias_table(w)
    assert np.all((prob >= 0) & (prob <= 1)) and np.all((alias >= 0) & (alias < len(w)))
    np.testing.assert_allclose(alias_distribution(prob, alias), w / w.sum(), rtol=1e-12, atol=1e-15)
    assert np.all(alias_distribution(prob, alias)[w == 0] == 0)  # a zero-area triangle is never chosen


@njit(cache=True)
def _sample_many(table, triangles, n, seed):
    np.random.seed(seed)  # numba's own generator
    tri = np.empty(n, np.int64)
    pts = np.empty((n, 3))
    for i in range(n):
        t, x, y, z = sample_on_emitter(0, table, triangles, np.random.random(), np.random.random(),
                                       np.random.random())
        tri[i] = t
        pts[i, 0], pts[i, 1], pts[i, 2] = x, y, z
    return tri, pts


def test_points_are_uniform_by_area_on_a_mesh_emitter():
    """Triangles of areas 1:2:3:4 (a fan in the z = 0 plane) get chosen in that proportion, and points fall
    uniformly inside their triangle (the barycentric coordinates' means are 1/3), within 5 standard errors."""
    base = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    triangles = np.array([[base[0], base[1], [0.0, 2.0 * a, 0.0]] for a in (1.0, 2.0, 3.0, 4.0)])
    areas = np.array([1.0, 2.0, 3.0, 4.0])
    prob, alias = alias_table(areas)
    table = EmitterArrays(np.ones(1), np.ones(1), np.array([0, 4]), np.arange(4), prob, alias, np.zeros(1, np.int8),
                          np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 4)), np.ones(4),
                          *environment_arrays(None, np.zeros(3))[0])  # one area emitter: triangles 0..3
    n = 200_000
    tri, pts = _sample_many(table, triangles, n, 3)
    share = areas / areas.sum()
    counts = np.bincount(tri, minlength=4)
    assert np.all(np.abs(counts / n - share) < 5 * np.sqrt(share * (1 - share) / n))
    assert np.all(pts[:, 2] == 0.0)
    for t in range(4):
        p = pts[tri == t]
        b1, b2 = p[:, 0], p[:, 1] / triangles[t, 2, 1]  # p = b1 v1 + b2 v2 with v0 at the origin
        assert np.all((b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1 + 1e-12))
        se = np.sqrt(1 / 18 / len(p))  # a barycentric coordinate of a uniform point has variance 1/18
        assert abs(b1.mean() - 1 / 3) < 5 * se and abs(b2.mean() - 1 / 3) < 5 * se
