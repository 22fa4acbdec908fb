"""Emitters and their sampling: an emitter is chosen by power; on an area emitter a triangle by area (alias
table) and a point uniformly on it; point, spot and directional lights are deltas; the environment gives a
direction by luminance (`probvis.environment`). Also the analytic irradiance of an emitter (Lambert's polygon
formula) for shading points the visibility estimator declares fully lit.

The direct-lighting segments a shading point makes from these samples are `probvis.shading`'s.
"""
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from .alias import alias_sample, alias_table
from .color import LUMINANCE
from .environment import environment_arrays
from .errors import ProbvisError
from .scene.scene import EMITTER_AREA, EMITTER_DIRECTIONAL, EMITTER_ENVIRONMENT, EMITTER_POINT, EMITTER_SPOT


class EmitterArrays(NamedTuple):
    """The emitter sampler as the kernels take it."""

    pmf: np.ndarray  # (e,) selection probability of each emitter (by power)
    area: np.ndarray  # (e,) its area (1 for a point or spot light: its samples carry intensity / d^2)
    offsets: np.ndarray  # (e + 1,) range of each emitter in `tris`
    tris: np.ndarray  # scene triangle ids of all emitting triangles, grouped by emitter
    tri_prob: np.ndarray  # alias table of each emitter's triangles by area: keep probability of column k ...
    tri_alias: np.ndarray  # ... and the column (index within the emitter) taken otherwise
    kind: np.ndarray  # (e,) EMITTER_AREA, EMITTER_POINT, EMITTER_SPOT, EMITTER_DIRECTIONAL or EMITTER_ENVIRONMENT
    position: np.ndarray  # (e, 3) of a point or spot light
    axis: np.ndarray  # (e, 3) a spot's unit axis
    cone: np.ndarray  # (e, 4) a spot's cos cutoff, cos beam width, cutoff angle and 1 / transition width
    sphere: np.ndarray  # (4,) centre and radius of the scene's bounding sphere (where directional light enters)
    # the environment emitter (`probvis.environment`; a black placeholder, scale zero, when the scene has none)
    env_image: np.ndarray  # (h, w + 1, 3) the map with its first column repeated at the end
    env_cell_prob: np.ndarray  # (w (h - 1),) alias table of the cells, row-major from the +y pole ...
    env_cell_alias: np.ndarray
    env_density: np.ndarray  # (h, w + 1) luminance x sin(theta) over its integral in (u, v): the (u, v) pdf at the
    # pixel centres, bilinear between them; (1, 1) where the cells are sampled uniformly in solid angle instead
    env_cell_pdf: np.ndarray  # (w (h - 1),) solid-angle density in each cell where sampled uniformly in it
    env_to_world: np.ndarray  # (3, 3) map frame -> world
    env_to_local: np.ndarray  # (3, 3) its inverse
    env_shift: float  # half a texel in u: pixel column j is centred at u = (j + 0.5) / w
    env_scale: np.ndarray  # (3,) the emitter's radiance scale: what a camera ray that misses sees, times the map


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


def build_emitter_sampler(scene):
    """The `EmitterSampler` of a scene's emitters."""
    e = scene.n_emitters
    lit = np.flatnonzero(scene.tri_emitter >= 0)  # the emitting triangles, by emitter, in scene order within one
    order = lit[np.argsort(scene.tri_emitter[lit], kind="stable")]
    tris = scene.triangles[order]
    tri_area = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
    counts = np.bincount(scene.tri_emitter[order], minlength=e)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    area = np.array([tri_area[offsets[i]:offsets[i + 1]].sum() for i in range(e)])
    tri_prob = np.empty(len(order))
    tri_alias = np.empty(len(order), np.int64)
    for i in range(e):
        tri_prob[offsets[i]:offsets[i + 1]], tri_alias[offsets[i]:offsets[i + 1]] = alias_table(
            tri_area[offsets[i]:offsets[i + 1]])
    kind = scene.emitter_kind
    lum = scene.emitter_radiance @ LUMINANCE
    lo, hi = scene.bounds()
    sphere = np.append(0.5 * (lo + hi), max(0.5 * float(np.linalg.norm(hi - lo)), 1e-6))
    env_scale = scene.emitter_radiance[kind == EMITTER_ENVIRONMENT]  # at most one environment
    env, env_integral = environment_arrays(scene.environment, env_scale[0] if len(env_scale) else np.zeros(3))
    # flux: pi A L of an area emitter, 4 pi I of a point light, about 2 pi (1 - cos cutoff) I of a spot, and
    # through the scene's bounding sphere E pi R^2 of a directional light and pi R^2 times the integral of L
    # over the sphere of an environment
    power = np.select([kind == EMITTER_AREA, kind == EMITTER_POINT, kind == EMITTER_SPOT, kind == EMITTER_ENVIRONMENT],
                      [np.pi * area * lum, 4 * np.pi * lum, 2 * np.pi * (1 - scene.emitter_cone[:, 0]) * lum,
                       np.pi * sphere[3] ** 2 * env_integral * lum],
                      np.pi * sphere[3] ** 2 * lum)
    area = np.where(kind == EMITTER_AREA, area, 1.0)
    if not np.any(power > 0):
        raise ProbvisError(f"scene '{scene.name}' has emitters, but all of them have zero power (a radiance, "
                           "intensity or irradiance of 0, or a scale of 0): the image would be black (as Mitsuba "
                           "renders it); give an emitter a positive one")
    pmf = power / power.sum()
    return EmitterSampler(EmitterArrays(pmf, area, offsets, order.astype(np.int64), tri_prob, tri_alias,
                                        kind.astype(np.int8), scene.emitter_position, scene.emitter_axis,
                                        scene.emitter_cone, sphere, *env), power)


@njit(cache=True, error_model="numpy", inline="always")
def sample_on_emitter(e, es, triangles, u1, u2, u3):
    """A point uniform on emitter `e` (`es` is the `EmitterArrays`): (scene triangle id, x, y, z); its pdf per
    unit area is 1 / area[e].

    The triangle comes from the alias table in O(1) with no branch on u1 (a binary search over the area CDF
    mispredicted half its branches), the point from Heitz's low-distortion square-to-triangle map of (u2, u3)
    (JCGT 2019): uniform, and without the square root of the usual map."""
    lo = es.offsets[e]
    t = es.tris[lo + alias_sample(es.tri_prob, es.tri_alias, lo, es.offsets[e + 1] - lo, u1)]
    upper = u3 > u2
    b0 = 0.5 * u2 if upper else u2 - 0.5 * u3
    b1 = u3 - 0.5 * u2 if upper else 0.5 * u3
    b2 = 1.0 - b0 - b1
    x = b0 * triangles[t, 0, 0] + b1 * triangles[t, 1, 0] + b2 * triangles[t, 2, 0]
    y = b0 * triangles[t, 0, 1] + b1 * triangles[t, 1, 1] + b2 * triangles[t, 2, 1]
    z = b0 * triangles[t, 0, 2] + b1 * triangles[t, 1, 2] + b2 * triangles[t, 2, 2]
    return t, x, y, z


@njit(cache=True, error_model="numpy", inline="always")
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
    # clip the triangle (relative to p) against the receiver's horizon plane: at most 4 vertices, each made
    # unit and summed edge by edge as it comes (no arrays: the fused kernels run without Numba's allocator)
    c = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0, 0.0, False)  # first vertex, previous vertex, count, sum, degenerate
    for i in range(3):
        j = (i + 1) % 3
        ax, ay, az = triangles[t, i, 0] - px, triangles[t, i, 1] - py, triangles[t, i, 2] - pz
        bx, by, bz = triangles[t, j, 0] - px, triangles[t, j, 1] - py, triangles[t, j, 2] - pz
        da = ax * nx + ay * ny + az * nz
        db = bx * nx + by * ny + bz * nz
        if da >= 0.0:
            c = _clip_vertex(c, ax, ay, az, nx, ny, nz)
        if (da >= 0.0) != (db >= 0.0):
            s = da / (da - db)
            c = _clip_vertex(c, ax + s * (bx - ax), ay + s * (by - ay), az + s * (bz - az), nx, ny, nz)
    if c[6] < 3 or c[8]:
        return 0.0
    return 0.5 * abs(c[7] + _edge_term(c[3], c[4], c[5], c[0], c[1], c[2], nx, ny, nz))


@njit(cache=True, error_model="numpy", inline="always")
def _clip_vertex(c, x, y, z, nx, ny, nz):
    """`triangle_irradiance`'s running state `c` after the clipped polygon's next vertex (x, y, z): made unit,
    the edge from the previous one added, a zero-length vertex marked degenerate."""
    r = np.sqrt(x * x + y * y + z * z)
    ux, uy, uz = x / r, y / r, z / r
    total = c[7] if c[6] == 0 else c[7] + _edge_term(c[3], c[4], c[5], ux, uy, uz, nx, ny, nz)
    if c[6] == 0:
        return (ux, uy, uz, ux, uy, uz, 1, total, r == 0.0)
    return (c[0], c[1], c[2], ux, uy, uz, c[6] + 1, total, c[8] or r == 0.0)


@njit(cache=True, error_model="numpy", inline="always")
def _edge_term(ax, ay, az, bx, by, bz, nx, ny, nz):
    """Lambert's term of the polygon edge between unit vectors a and b for normal n."""
    cx = ay * bz - az * by
    cy = az * bx - ax * bz
    cz = ax * by - ay * bx
    sn = np.sqrt(cx * cx + cy * cy + cz * cz)
    if sn == 0.0:
        return 0.0
    cs = ax * bx + ay * by + az * bz
    return np.arctan2(sn, cs) * (cx * nx + cy * ny + cz * nz) / sn


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
