"""Stage 3 of a render: emitter sampling. An emitter is chosen by power; on an area emitter a triangle by area
(alias table) and a point uniformly on it; point, spot and directional lights are deltas; an environment
(Mitsuba's `envmap` or `constant`) gives a direction by luminance. Also the analytic irradiance of an emitter
(Lambert's polygon formula) for shading points the visibility estimator declares fully lit.

`sample_emitters` fills, for every shading point, `shadow_rays` slots of shadow segments with their
unoccluded contributions; `point_samples` is its per-point body, shared with the fused exact kernel.
"""
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from .cases import CASE_LIT, CASE_MASK, CASE_PENUMBRA, CASE_UNKNOWN, CASE_VERIFIED
from .errors import ProbvisError
from .parallel import spread
from .rng import uniform
from .scene.scene import EMITTER_AREA, EMITTER_DIRECTIONAL, EMITTER_ENVIRONMENT, EMITTER_POINT, EMITTER_SPOT

LUMINANCE = np.array([0.212671, 0.715160, 0.072169])
POINTS_PER_BLOCK = 64  # shading points per parallel work item of `sample_emitters`


class EmitterArrays(NamedTuple):
    """The emitter sampler as the kernels take it."""

    pmf: np.ndarray  # (e,) selection probability of each emitter (by power)
    area: np.ndarray  # (e,) its area (1 for a point or spot light: its samples carry intensity / d^2)
    offsets: np.ndarray  # (e + 1,) range of each emitter in `tris`
    tris: np.ndarray  # scene triangle ids of all emitting triangles, grouped by emitter
    tri_prob: np.ndarray  # alias table of each emitter's triangles by area: keep probability of column k ...
    tri_alias: np.ndarray  # ... and the column (index within the emitter) taken otherwise
    kind: np.ndarray  # (e,) EMITTER_AREA, EMITTER_POINT, EMITTER_SPOT or EMITTER_DIRECTIONAL
    position: np.ndarray  # (e, 3) of a point or spot light
    axis: np.ndarray  # (e, 3) a spot's unit axis
    cone: np.ndarray  # (e, 4) a spot's cos cutoff, cos beam width, cutoff angle and 1 / transition width
    sphere: np.ndarray  # (4,) centre and radius of the scene's bounding sphere (where directional light enters)
    # The environment emitter (a black placeholder when the scene has none). Its radiance is Mitsuba's:
    # bilinear between pixel centres of the latitude-longitude map (u = atan2(x, -z) / 2 pi, v = acos(y) / pi
    # in the map's frame), the first column repeated after the last. Sampling picks a cell between four pixel
    # centres by its largest corner luminance times its solid angle (alias table), then a direction uniform in
    # solid angle within it: the pdf is constant per cell and positive wherever the radiance is not zero.
    env_image: np.ndarray  # (h, w + 1, 3) the map with its first column repeated at the end
    env_cell_prob: np.ndarray  # (w (h - 1),) alias table of the cells, row-major from the +y pole ...
    env_cell_alias: np.ndarray
    env_cell_pdf: np.ndarray  # (w (h - 1),) solid-angle density of a direction in each cell
    env_to_world: np.ndarray  # (3, 3) map frame -> world
    env_to_local: np.ndarray  # (3, 3) its inverse
    env_shift: float  # half a texel in u: pixel column j is centred at u = (j + 0.5) / w


@dataclass
class EmitterSampler:
    """How emitters are sampled (`arrays`, for the kernels) and their emitted flux (`power`)."""

    arrays: EmitterArrays
    power: np.ndarray  # (e,) emitted flux (luminance of radiance x pi x area)

    @property
    def emitter_pmf(self):
        return self.arrays.pmf

    @property
    def emitter_area(self):
        return self.arrays.area


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


def environment_arrays(env):
    """The `env_*` fields of `EmitterArrays` for a scene's `Environment` (None: a black placeholder), and the
    integral of its luminance over the sphere (for its power)."""
    image = np.zeros((2, 1, 3)) if env is None else env.image
    h, w = image.shape[:2]
    ext = np.ascontiguousarray(np.concatenate([image, image[:, :1]], axis=1))
    lum = np.abs(ext) @ LUMINANCE
    corners = np.stack([lum[:-1, :-1], lum[:-1, 1:], lum[1:, :-1], lum[1:, 1:]])
    cos_t = np.cos(np.linspace(0.0, np.pi, h))
    solid = (2.0 * np.pi / w) * (cos_t[:-1] - cos_t[1:])[:, None] * np.ones((1, w))
    weight = (corners.max(axis=0) * solid).ravel()
    total = weight.sum()
    cell_pdf = weight / (total * solid.ravel()) if total > 0 else np.zeros_like(weight)
    prob, alias = alias_table(weight)
    to_world = np.eye(3) if env is None else env.to_world
    integral = float((corners.mean(axis=0) * solid).sum())
    return (ext, prob, alias, cell_pdf, to_world, np.linalg.inv(to_world), 0.5 / w), integral


@njit(cache=True, error_model="numpy", inline="always")
def environment_radiance(es, dx, dy, dz):
    """Mitsuba's envmap radiance (before its scale) arriving from world direction d (any length)."""
    m = es.env_to_local
    x = m[0, 0] * dx + m[0, 1] * dy + m[0, 2] * dz
    y = m[1, 0] * dx + m[1, 1] * dy + m[1, 2] * dz
    z = m[2, 0] * dx + m[2, 1] * dy + m[2, 2] * dz
    r = math.sqrt(x * x + y * y + z * z)
    u = math.atan2(x, -z) * (0.5 / math.pi) - es.env_shift
    u -= math.floor(u)
    v = math.acos(min(max(y / r, -1.0), 1.0)) / math.pi
    h, w1 = es.env_image.shape[0], es.env_image.shape[1]
    return _bilinear(es.env_image, u * (w1 - 1), v * (h - 1))


@njit(cache=True, error_model="numpy", inline="always")
def _bilinear(image, fx, fy):
    """Bilinear interpolation of `image` at pixel coordinates (fx, fy), pixel (i, j) at (j, i)."""
    i = min(int(fy), image.shape[0] - 2)
    j = min(int(fx), image.shape[1] - 2)
    wx, wy = fx - j, fy - i
    out = [0.0, 0.0, 0.0]
    for c in range(3):
        top = (1.0 - wx) * image[i, j, c] + wx * image[i, j + 1, c]
        bottom = (1.0 - wx) * image[i + 1, j, c] + wx * image[i + 1, j + 1, c]
        out[c] = (1.0 - wy) * top + wy * bottom
    return out[0], out[1], out[2]


@njit(cache=True, error_model="numpy", inline="always")
def sample_environment(es, u1, u2, u3):
    """A world direction towards the environment, by its cells: (dx, dy, dz, solid-angle pdf, and the radiance
    r, g, b before the emitter's scale)."""
    h, w = es.env_image.shape[0], es.env_image.shape[1] - 1
    n = es.env_cell_prob.shape[0]
    x = u1 * n
    k = min(np.int64(x), n - 1)
    other = es.env_cell_alias[k]
    k = k if x - k < es.env_cell_prob[k] else other
    i, j = k // w, k % w
    step = math.pi / (h - 1)
    c0, c1 = math.cos(i * step), math.cos((i + 1) * step)
    cos_t = c0 - u3 * (c0 - c1)
    theta = math.acos(min(max(cos_t, -1.0), 1.0))
    sin_t = math.sqrt(max(0.0, 1.0 - cos_t * cos_t))
    phi = 2.0 * math.pi * ((j + u2) / w + es.env_shift)
    lx, ly, lz = math.sin(phi) * sin_t, cos_t, -math.cos(phi) * sin_t
    m = es.env_to_world
    dx = m[0, 0] * lx + m[0, 1] * ly + m[0, 2] * lz
    dy = m[1, 0] * lx + m[1, 1] * ly + m[1, 2] * lz
    dz = m[2, 0] * lx + m[2, 1] * ly + m[2, 2] * lz
    r = math.sqrt(dx * dx + dy * dy + dz * dz)
    l0, l1, l2 = _bilinear(es.env_image, j + u2, min(theta / step, h - 1.0))
    return dx / r, dy / r, dz / r, es.env_cell_pdf[k], l0, l1, l2


def build_emitter_sampler(scene):
    """The `EmitterSampler` of a scene's emitters."""
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
    kind = scene.emitter_kind
    lum = scene.emitter_radiance @ LUMINANCE
    lo, hi = scene.bounds()
    sphere = np.append(0.5 * (lo + hi), max(0.5 * float(np.linalg.norm(hi - lo)), 1e-6))
    env, env_integral = environment_arrays(scene.environment)
    # flux: pi A L of an area emitter, 4 pi I of a point light, about 2 pi (1 - cos cutoff) I of a spot, and
    # through the scene's bounding sphere E pi R^2 of a directional light and pi R^2 times the integral of L
    # over the sphere of an environment
    power = np.select([kind == EMITTER_AREA, kind == EMITTER_POINT, kind == EMITTER_SPOT, kind == EMITTER_ENVIRONMENT],
                      [np.pi * area * lum, 4 * np.pi * lum, 2 * np.pi * (1 - scene.emitter_cone[:, 0]) * lum,
                       np.pi * sphere[3] ** 2 * env_integral * lum],
                      np.pi * sphere[3] ** 2 * lum)
    area = np.where(kind == EMITTER_AREA, area, 1.0)
    if not np.any(power > 0):
        raise ProbvisError(f"scene '{scene.name}' has emitters, but all of them have zero power")
    pmf = power / power.sum()
    return EmitterSampler(EmitterArrays(pmf, area, offsets, order.astype(np.int64), tri_prob, tri_alias,
                                        kind.astype(np.int8), scene.emitter_position, scene.emitter_axis,
                                        scene.emitter_cone, sphere, *env), power)


@njit(cache=True, error_model="numpy", inline="always")
def is_sampled(case):
    """Whether an emitter of this occlusion case gets shadow rays (lit ones are integrated, shadowed skipped,
    unless verified)."""
    c = case & CASE_MASK
    return c == CASE_UNKNOWN or c == CASE_PENUMBRA or (case & CASE_VERIFIED) != 0


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
def sample_on_emitter(e, es, triangles, u1, u2, u3):
    """A point uniform on emitter `e` (`es` is the `EmitterArrays`): (scene triangle id, x, y, z); its pdf per
    unit area is 1 / area[e].

    The triangle comes from the alias table in O(1) with no branch on u1 (a binary search over the area CDF
    mispredicted half its branches), the point from Heitz's low-distortion square-to-triangle map of (u2, u3)
    (JCGT 2019): uniform, and without the square root of the usual map."""
    offsets, tris, prob, alias = es.offsets, es.tris, es.tri_prob, es.tri_alias
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


@njit(cache=True, error_model="numpy", inline="always")
def delta_falloff(es, e, dx, dy, dz):
    """Emitted intensity of point or spot light `e` towards direction d (any length), relative to its
    `intensity`: 1 for a point light; Mitsuba's spot falloff, linear in angle from the beam width to the
    cutoff."""
    if es.kind[e] != EMITTER_SPOT:
        return 1.0
    cos_t = (dx * es.axis[e, 0] + dy * es.axis[e, 1] + dz * es.axis[e, 2]) / math.sqrt(dx * dx + dy * dy + dz * dz)
    if cos_t <= es.cone[e, 0]:
        return 0.0
    if cos_t >= es.cone[e, 1]:
        return 1.0
    return (es.cone[e, 2] - math.acos(min(cos_t, 1.0))) * es.cone[e, 3]


@njit(cache=True, error_model="numpy")
def emitter_irradiance(e, es, triangles, px, py, pz, nx, ny, nz):
    """Cosine-weighted solid angle of all of emitter `e`'s front-facing triangles above p's horizon (for a
    point or spot light: cos / d^2 times its falloff, so that intensity x this is the irradiance; for an
    environment pi, exact for a constant one, whose image is ones: an envmap's lit points are sampled instead)."""
    if es.kind[e] == EMITTER_ENVIRONMENT:
        return math.pi
    if es.kind[e] == EMITTER_DIRECTIONAL:
        return max(-(nx * es.axis[e, 0] + ny * es.axis[e, 1] + nz * es.axis[e, 2]), 0.0)
    if es.kind[e] != EMITTER_AREA:
        wx, wy, wz = es.position[e, 0] - px, es.position[e, 1] - py, es.position[e, 2] - pz
        d2 = wx * wx + wy * wy + wz * wz
        dot = nx * wx + ny * wy + nz * wz
        return max(dot, 0.0) / (d2 * math.sqrt(d2)) * delta_falloff(es, e, -wx, -wy, -wz)
    total = 0.0
    for k in range(es.offsets[e], es.offsets[e + 1]):
        total += triangle_irradiance(triangles, es.tris[k], px, py, pz, nx, ny, nz)
    return total


@njit(cache=True, error_model="numpy", inline="always")
def _emitter_segment(slot, le, scale, rgb, u, es, triangles, fnormals, p, s, gn, eps, contrib, s_org, s_dir,
                     s_emit, active):
    """Fill shadow slot `slot` with a point sampled on emitter `le` (random numbers `u`) seen from shading
    point p (shading normal s, geometric normal gn): segment, contribution `rgb` x `scale` x cos cos / d^2
    (`scale` holds area / (pdf of the emitter x samples x pi)) and the active flag. No branches: the slot is
    written whether or not the emitter point faces p, and `active` says which."""
    t0 = t1 = t2 = 1.0  # the environment's radiance / pdf of its direction, per channel
    if es.kind[le] == EMITTER_AREA:
        lt, yx, yy, yz = sample_on_emitter(le, es, triangles, u[0], u[1], u[2])
        wx, wy, wz = yx - p[0], yy - p[1], yz - p[2]
        d2 = wx * wx + wy * wy + wz * wz
        # cosines times |w|: their signs need no square root, and cos_x cos_y / d2 = dot_x dot_y / d2^2
        dot_x = s[0] * wx + s[1] * wy + s[2] * wz
        dot_y = -(fnormals[lt, 0] * wx + fnormals[lt, 1] * wy + fnormals[lt, 2] * wz)
    elif es.kind[le] == EMITTER_DIRECTIONAL:  # E cos_x: the segment leaves the scene against the light's travel
        r2 = 2.0 * es.sphere[3]
        yx, yy, yz = p[0] - es.axis[le, 0] * r2, p[1] - es.axis[le, 1] * r2, p[2] - es.axis[le, 2] * r2
        wx, wy, wz = yx - p[0], yy - p[1], yz - p[2]
        d2 = wx * wx + wy * wy + wz * wz
        dot_x = s[0] * wx + s[1] * wy + s[2] * wz
        dot_y = d2 * math.sqrt(d2)  # so that dot_x dot_y / d2^2 = cos_x
    elif es.kind[le] == EMITTER_ENVIRONMENT:  # L(w) cos_x / pdf(w): the segment leaves the scene along w
        dx, dy, dz, pdf, t0, t1, t2 = sample_environment(es, u[0], u[1], u[2])
        inv = 1.0 / pdf if pdf > 0.0 else 0.0
        t0, t1, t2 = t0 * inv, t1 * inv, t2 * inv
        r2 = 2.0 * es.sphere[3]
        yx, yy, yz = p[0] + dx * r2, p[1] + dy * r2, p[2] + dz * r2
        wx, wy, wz = yx - p[0], yy - p[1], yz - p[2]
        d2 = wx * wx + wy * wy + wz * wz
        dot_x = s[0] * wx + s[1] * wy + s[2] * wz
        dot_y = d2 * math.sqrt(d2) if pdf > 0.0 else 0.0
    else:  # a point or spot light: cos_x I / d2 = dot_x |w| / d2^2, times a spot's falloff
        yx, yy, yz = es.position[le, 0], es.position[le, 1], es.position[le, 2]
        wx, wy, wz = yx - p[0], yy - p[1], yz - p[2]
        d2 = wx * wx + wy * wy + wz * wz
        dot_x = s[0] * wx + s[1] * wy + s[2] * wz
        dot_y = math.sqrt(d2) * delta_falloff(es, le, -wx, -wy, -wz)
    g = dot_x * dot_y * scale / (d2 * d2)
    off = eps if gn[0] * wx + gn[1] * wy + gn[2] * wz > 0.0 else -eps
    ox, oy, oz = p[0] + off * gn[0], p[1] + off * gn[1], p[2] + off * gn[2]
    contrib[slot, 0], contrib[slot, 1], contrib[slot, 2] = rgb[0] * g * t0, rgb[1] * g * t1, rgb[2] * g * t2
    s_org[slot, 0], s_org[slot, 1], s_org[slot, 2] = ox, oy, oz
    s_dir[slot, 0], s_dir[slot, 1], s_dir[slot, 2] = yx - ox, yy - oy, yz - oz
    s_emit[slot] = le
    active[slot] = (dot_x > 0.0) & (dot_y > 0.0)


@njit(cache=True, error_model="numpy", inline="always")
def point_samples(i, geom, es, prim, pos, nrm, mat, refl, cases, keys, n_shadow, base, s_org, s_dir, contrib, s_emit,
                  active, dense):
    """Direct light at shading point `i` (`geom` is the `SceneArrays`, `refl` the points' albedo), per emitter as
    the visibility estimator's `cases` say:

    lit (case 1) emitters are integrated analytically (Lambert's polygon formula, no noise, no rays),
    shadowed (case 2) ones contribute nothing, and the others, verified lit and shadowed ones included, are
    sampled: `n_shadow` emitter samples (emitter
    by power among the sampled ones, point uniform by area) in slots base..base + n_shadow - 1. Fills, per
    slot, segment origin and direction, the unoccluded contribution (already divided by pdf and n_shadow), the
    emitter id and the active flag (the other outputs of an inactive slot are meaningless). With `dense` (a
    constant in each caller) only the active samples are kept, in slots base..base + m - 1 (a sample is
    written at base + m and kept by advancing m). Returns the analytic radiance and m (0 without `dense`).
    """
    triangles, fnormals, radiance = geom.triangles, geom.face_normals, geom.emitter_radiance
    pmf, area = es.pmf, es.area
    inv_pi = 1.0 / math.pi
    a0 = a1 = a2 = 0.0
    m = 0
    mi = mat[i]
    if mi < 0:
        for j in range(n_shadow):
            active[base + j] = False
        return a0, a1, a2, m
    tri = prim[i]
    p = (pos[i, 0], pos[i, 1], pos[i, 2])
    s = (nrm[i, 0], nrm[i, 1], nrm[i, 2])
    for e in range(pmf.shape[0]):
        if cases[i, e] & CASE_MASK == CASE_LIT:
            f = emitter_irradiance(e, es, triangles, p[0], p[1], p[2], s[0], s[1], s[2]) * inv_pi
            a0 += refl[i, 0] * radiance[e, 0] * f
            a1 += refl[i, 1] * radiance[e, 1] * f
            a2 += refl[i, 2] * radiance[e, 2] * f
    total, only = sampled_share(pmf, cases, i)
    if total <= 0.0:
        for j in range(n_shadow):
            active[base + j] = False
        return a0, a1, a2, m
    gn = (fnormals[tri, 0], fnormals[tri, 1], fnormals[tri, 2])
    eps = 1e-9 * (1.0 + max(abs(p[0]), abs(p[1]), abs(p[2])))
    key = keys[i]
    if only >= 0:  # a single emitter: no choice (its random dimension is simply not drawn)
        scale = area[only] * inv_pi / n_shadow
        rgb = (refl[i, 0] * radiance[only, 0], refl[i, 1] * radiance[only, 1], refl[i, 2] * radiance[only, 2])
        for j in range(n_shadow):
            u = (uniform(key, 3 + 4 * j), uniform(key, 4 + 4 * j), uniform(key, 5 + 4 * j))
            slot = base + m if dense else base + j
            _emitter_segment(slot, only, scale, rgb, u, es, triangles, fnormals, p, s, gn, eps, contrib, s_org,
                             s_dir, s_emit, active)
            if dense:
                m += active[slot]
        return a0, a1, a2, m
    for j in range(n_shadow):
        le, p_e = choose_emitter(pmf, cases, i, total, uniform(key, 2 + 4 * j))
        rgb = (refl[i, 0] * radiance[le, 0], refl[i, 1] * radiance[le, 1], refl[i, 2] * radiance[le, 2])
        u = (uniform(key, 3 + 4 * j), uniform(key, 4 + 4 * j), uniform(key, 5 + 4 * j))
        slot = base + m if dense else base + j
        _emitter_segment(slot, le, area[le] * inv_pi / (p_e * n_shadow), rgb, u, es, triangles, fnormals, p, s,
                         gn, eps, contrib, s_org, s_dir, s_emit, active)
        if dense:
            m += active[slot]
    return a0, a1, a2, m


@njit(cache=True, parallel=True, error_model="numpy")
def sample_emitters(geom, es, prim, pos, nrm, mat, albedo, cases, keys, n_shadow, s_org, s_dir, contrib, s_emit,
                    active):
    """`point_samples` of every shading point, point i in slots i * n_shadow onwards; returns the analytic
    radiance per point."""
    n = prim.shape[0]
    analytic = np.zeros((n, 3))
    n_blocks = (n + POINTS_PER_BLOCK - 1) // POINTS_PER_BLOCK
    for it in prange(n_blocks):
        blk = spread(it, n_blocks)
        for i in range(blk * POINTS_PER_BLOCK, min(n, (blk + 1) * POINTS_PER_BLOCK)):
            analytic[i, 0], analytic[i, 1], analytic[i, 2] = point_samples(
                i, geom, es, prim, pos, nrm, mat, albedo, cases, keys, n_shadow, i * n_shadow, s_org, s_dir, contrib,
                s_emit, active, False)[:3]
    return analytic


@njit(cache=True, parallel=True, error_model="numpy")
def add_environment(emitted, prim, dirs, es, scale):
    """Add the environment's radiance (times `scale`, per channel) to the camera rays that miss the scene."""
    for i in prange(prim.shape[0]):
        if prim[i] < 0:
            l0, l1, l2 = environment_radiance(es, dirs[i, 0], dirs[i, 1], dirs[i, 2])
            emitted[i, 0] += l0 * scale[0]
            emitted[i, 1] += l1 * scale[1]
            emitted[i, 2] += l2 * scale[2]
