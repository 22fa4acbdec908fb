"""Area emitters: choose an emitter by power, a triangle by area (alias table), a point uniformly on it."""
from dataclasses import dataclass

import numpy as np
from numba import njit

from .cases import CASE_PENUMBRA, CASE_UNKNOWN
from .errors import ProbvisError

_LUMINANCE = np.array([0.212671, 0.715160, 0.072169])


@dataclass
class EmitterSampler:
    emitter_pmf: np.ndarray  # (e,)
    emitter_area: np.ndarray  # (e,)
    offsets: np.ndarray  # (e + 1,) range of each emitter in `tris`
    tris: np.ndarray  # scene triangle ids of all emitting triangles, grouped by emitter
    tri_prob: np.ndarray  # alias table of each emitter's triangles by area: keep probability of column k ...
    tri_alias: np.ndarray  # ... and the column (index within the emitter) taken otherwise
    power: np.ndarray  # (e,) emitted flux (luminance of radiance x pi x area)

    @property
    def triangle_table(self):
        """What `sample_on_emitter` needs: (offsets, tris, tri_prob, tri_alias)."""
        return self.offsets, self.tris, self.tri_prob, self.tri_alias

    @property
    def arrays(self):
        return self.emitter_pmf, self.emitter_area, self.triangle_table


@njit(cache=True, error_model="numpy")
def alias_table(weights):
    """Walker's alias table of non-negative `weights` (Vose's construction): column k = floor(u n) is kept
    with probability prob[k], else alias[k] is taken, so index i comes out with probability w_i / sum(w)."""
    n = weights.shape[0]
    prob = np.ones(n)
    alias = np.arange(n)
    total = weights.sum()
    if total <= 0.0:
        return prob, alias
    scaled = weights * (n / total)
    small = np.empty(n, np.int64)
    large = np.empty(n, np.int64)
    ns = nl = 0
    for i in range(n):
        if scaled[i] < 1.0:
            small[ns] = i
            ns += 1
        else:
            large[nl] = i
            nl += 1
    while ns > 0 and nl > 0:
        ns -= 1
        s = small[ns]
        g = large[nl - 1]
        prob[s] = scaled[s]
        alias[s] = g
        scaled[g] -= 1.0 - scaled[s]
        if scaled[g] < 1.0:  # g now falls short itself: it joins the small ones, to be topped up
            nl -= 1
            small[ns] = g
            ns += 1
    return prob, alias


def build_emitter_sampler(scene):
    e = scene.n_emitters
    tri_area = 0.5 * np.linalg.norm(np.cross(scene.triangles[:, 1] - scene.triangles[:, 0],
                                             scene.triangles[:, 2] - scene.triangles[:, 0]), axis=1)
    order = np.argsort(scene.tri_emitter, kind="stable")
    order = order[scene.tri_emitter[order] >= 0]
    counts = np.bincount(scene.tri_emitter[order], minlength=e)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    area = np.array([tri_area[order[offsets[i]:offsets[i + 1]]].sum() for i in range(e)])
    tri_prob = np.empty(len(order))
    tri_alias = np.empty(len(order), np.int64)
    for i in range(e):
        tri_prob[offsets[i]:offsets[i + 1]], tri_alias[offsets[i]:offsets[i + 1]] = alias_table(
            tri_area[order[offsets[i]:offsets[i + 1]]])
    power = np.pi * area * (scene.emitter_radiance @ _LUMINANCE)
    if not np.any(power > 0):
        raise ProbvisError(f"scene '{scene.name}' has emitters, but all of them have zero power")
    pmf = power / power.sum()
    return EmitterSampler(pmf, area, offsets, order.astype(np.int64), tri_prob, tri_alias, power)


@njit(cache=True, error_model="numpy", inline="always")
def is_sampled(case):
    """Whether an emitter of this occlusion case gets shadow rays (lit ones are integrated, shadowed skipped)."""
    return case == CASE_UNKNOWN or case == CASE_PENUMBRA


@njit(cache=True, error_model="numpy", inline="always")
def sampled_share(pmf, cases, i):
    """Total selection probability of the emitters point `i` samples (`cases[i, e]` unknown or penumbra), and
    that emitter's id if there is only one (else -1: a choice is needed)."""
    total = 0.0
    only = -1
    count = 0
    for e in range(pmf.shape[0]):
        if is_sampled(cases[i, e]):
            total += pmf[e]
            only = e
            count += 1
    return total, only if count == 1 else -1


@njit(cache=True, error_model="numpy", inline="always")
def choose_emitter(pmf, cases, i, total, u):
    """An emitter among those point `i` samples, by power, given their `sampled_share` `total` (> 0):
    (emitter id, its selection probability)."""
    target = u * total
    last = -1
    acc = 0.0
    for e in range(pmf.shape[0]):
        if is_sampled(cases[i, e]):
            last = e
            acc += pmf[e]
            if acc > target:
                return e, pmf[e] / total
    return last, pmf[last] / total  # only reached through rounding when u is within an ulp of 1


@njit(cache=True, error_model="numpy", inline="always")
def sample_on_emitter(e, table, triangles, u1, u2, u3):
    """A point uniform on emitter `e` (`table` is `EmitterSampler.triangle_table`): (scene triangle id, x, y,
    z); its pdf per unit area is 1 / area[e].

    The triangle comes from the alias table in O(1) with no branch on u1 (a binary search over the area CDF
    mispredicted half its branches), the point from Heitz's low-distortion square-to-triangle map of (u2, u3)
    (JCGT 2019): uniform, and without the square root of the usual map."""
    offsets, tris, prob, alias = table
    lo = offsets[e]
    n = offsets[e + 1] - lo
    x = u1 * n
    k = min(np.int64(x), n - 1)
    other = alias[lo + k]  # loaded unconditionally: an array read inside the select costs Numba a refcount
    k = k if x - k < prob[lo + k] else other
    t = tris[lo + k]
    upper = u3 > u2
    b0 = 0.5 * u2 if upper else u2 - 0.5 * u3
    b1 = u3 - 0.5 * u2 if upper else 0.5 * u3
    b2 = 1.0 - b0 - b1
    x = b0 * triangles[t, 0, 0] + b1 * triangles[t, 1, 0] + b2 * triangles[t, 2, 0]
    y = b0 * triangles[t, 0, 1] + b1 * triangles[t, 1, 1] + b2 * triangles[t, 2, 1]
    z = b0 * triangles[t, 0, 2] + b1 * triangles[t, 1, 2] + b2 * triangles[t, 2, 2]
    return t, x, y, z


@njit(cache=True, error_model="numpy")
def triangle_irradiance(triangles, t, px, py, pz, nx, ny, nz):
    """Cosine-weighted solid angle (the integral of max(0, n.w) dw) of triangle `t` seen from p with normal n,
    counting only its front side and only the part above p's horizon (Lambert's polygon formula after
    clipping the triangle to the half-space n.(x - p) >= 0). Radiance L of the triangle gives irradiance L x
    this; a Lambertian surface of albedo rho reflects rho / pi times that."""
    ex = (triangles[t, 1, 0] - triangles[t, 0, 0], triangles[t, 1, 1] - triangles[t, 0, 1],
          triangles[t, 1, 2] - triangles[t, 0, 2])
    fx = (triangles[t, 2, 0] - triangles[t, 0, 0], triangles[t, 2, 1] - triangles[t, 0, 1],
          triangles[t, 2, 2] - triangles[t, 0, 2])
    lx = ex[1] * fx[2] - ex[2] * fx[1]
    ly = ex[2] * fx[0] - ex[0] * fx[2]
    lz = ex[0] * fx[1] - ex[1] * fx[0]
    if lx * (px - triangles[t, 0, 0]) + ly * (py - triangles[t, 0, 1]) + lz * (pz - triangles[t, 0, 2]) <= 0.0:
        return 0.0  # p is behind the emitting side
    # clip the triangle (relative to p) against the receiver's horizon plane: at most 4 vertices
    vx = np.empty(4)
    vy = np.empty(4)
    vz = np.empty(4)
    m = 0
    for i in range(3):
        j = (i + 1) % 3
        ax, ay, az = triangles[t, i, 0] - px, triangles[t, i, 1] - py, triangles[t, i, 2] - pz
        bx, by, bz = triangles[t, j, 0] - px, triangles[t, j, 1] - py, triangles[t, j, 2] - pz
        da = ax * nx + ay * ny + az * nz
        db = bx * nx + by * ny + bz * nz
        if da >= 0.0:
            vx[m], vy[m], vz[m] = ax, ay, az
            m += 1
        if (da >= 0.0) != (db >= 0.0):
            s = da / (da - db)
            vx[m], vy[m], vz[m] = ax + s * (bx - ax), ay + s * (by - ay), az + s * (bz - az)
            m += 1
    if m < 3:
        return 0.0
    for i in range(m):
        r = np.sqrt(vx[i] * vx[i] + vy[i] * vy[i] + vz[i] * vz[i])
        if r == 0.0:
            return 0.0
        vx[i] /= r
        vy[i] /= r
        vz[i] /= r
    total = 0.0
    for i in range(m):
        j = (i + 1) % m
        cx = vy[i] * vz[j] - vz[i] * vy[j]
        cy = vz[i] * vx[j] - vx[i] * vz[j]
        cz = vx[i] * vy[j] - vy[i] * vx[j]
        sn = np.sqrt(cx * cx + cy * cy + cz * cz)
        if sn == 0.0:
            continue
        cs = vx[i] * vx[j] + vy[i] * vy[j] + vz[i] * vz[j]
        total += np.arctan2(sn, cs) * (cx * nx + cy * ny + cz * nz) / sn
    return 0.5 * abs(total)


@njit(cache=True, error_model="numpy")
def emitter_irradiance(e, offsets, tris, triangles, px, py, pz, nx, ny, nz):
    """Cosine-weighted solid angle of all of emitter `e`'s front-facing triangles above p's horizon."""
    total = 0.0
    for k in range(offsets[e], offsets[e + 1]):
        total += triangle_irradiance(triangles, tris[k], px, py, pz, nx, ny, nz)
    return total
