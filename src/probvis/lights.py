"""Area emitters: choose an emitter by power, a triangle by area, a point uniformly on it."""
from dataclasses import dataclass

import numpy as np
from numba import njit

from .errors import ProbvisError

_LUMINANCE = np.array([0.212671, 0.715160, 0.072169])


@dataclass
class EmitterSampler:
    emitter_cdf: np.ndarray  # (e,) inclusive cumulative selection probability
    emitter_pmf: np.ndarray  # (e,)
    emitter_area: np.ndarray  # (e,)
    offsets: np.ndarray  # (e + 1,) range of each emitter in `tris`
    tris: np.ndarray  # scene triangle ids of all emitting triangles, grouped by emitter
    tri_cdf: np.ndarray  # inclusive cumulative area fraction within each emitter
    power: np.ndarray  # (e,) emitted flux (luminance of radiance x pi x area)

    @property
    def arrays(self):
        return self.emitter_cdf, self.emitter_pmf, self.emitter_area, self.offsets, self.tris, self.tri_cdf


def build_emitter_sampler(scene):
    e = scene.n_emitters
    tri_area = 0.5 * np.linalg.norm(np.cross(scene.triangles[:, 1] - scene.triangles[:, 0],
                                             scene.triangles[:, 2] - scene.triangles[:, 0]), axis=1)
    order = np.argsort(scene.tri_emitter, kind="stable")
    order = order[scene.tri_emitter[order] >= 0]
    counts = np.bincount(scene.tri_emitter[order], minlength=e)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    area = np.array([tri_area[order[offsets[i]:offsets[i + 1]]].sum() for i in range(e)])
    tri_cdf = np.empty(len(order))
    for i in range(e):
        a = tri_area[order[offsets[i]:offsets[i + 1]]]
        tri_cdf[offsets[i]:offsets[i + 1]] = np.cumsum(a) / a.sum() if a.sum() > 0 else 1.0
        tri_cdf[offsets[i + 1] - 1] = 1.0
    power = np.pi * area * (scene.emitter_radiance @ _LUMINANCE)
    if not np.any(power > 0):
        raise ProbvisError(f"scene '{scene.name}' has emitters, but all of them have zero power")
    pmf = power / power.sum()
    cdf = np.cumsum(pmf)
    cdf[-1] = 1.0  # u < 1 then never selects past the last emitter of non-zero power
    return EmitterSampler(cdf, pmf, area, offsets, order.astype(np.int64), tri_cdf, power)


@njit(cache=True, error_model="numpy", inline="always")
def _search(cdf, lo, hi, u):
    """Smallest index in [lo, hi) whose inclusive cdf exceeds u (hi - 1 if none does)."""
    a, b = lo, hi - 1
    while a < b:
        mid = (a + b) // 2
        if cdf[mid] > u:
            b = mid
        else:
            a = mid + 1
    return a


@njit(cache=True, error_model="numpy")
def sample_emitter(cdf, pmf, area, offsets, tris, tri_cdf, triangles, u0, u1, u2, u3):
    """A point on an emitter: (scene triangle id, emitter id, x, y, z, pdf per unit area).

    The first six arguments are `EmitterSampler.arrays`, passed one by one (cheaper than a tuple per call).
    """
    e = _search(cdf, 0, cdf.shape[0], u0)
    t = tris[_search(tri_cdf, offsets[e], offsets[e + 1], u1)]
    su = np.sqrt(u2)
    b0 = 1.0 - su
    b1 = u3 * su
    b2 = 1.0 - b0 - b1
    x = b0 * triangles[t, 0, 0] + b1 * triangles[t, 1, 0] + b2 * triangles[t, 2, 0]
    y = b0 * triangles[t, 0, 1] + b1 * triangles[t, 1, 1] + b2 * triangles[t, 2, 1]
    z = b0 * triangles[t, 0, 2] + b1 * triangles[t, 1, 2] + b2 * triangles[t, 2, 2]
    return t, e, x, y, z, pmf[e] / area[e]
