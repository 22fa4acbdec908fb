"""Stage 2 of a render: the surface interaction at each camera ray's closest hit.

With the integrator's `hide_emitters` a camera ray passes through emitting shapes to what lies behind them
(`camera_hits`), as in Mitsuba 3.9: neither their emission nor what they reflect is seen, from either side.
Gives the radiance of an emitter seen directly (or of the environment, for a ray that misses; neither with the
integrator's `hide_emitters`), the shading point, its shading normal turned to the camera's side, its material
and its albedo (the material's reflectance, or its texture at the point's uv). As in Mitsuba 3, a plain
`diffuse` BSDF is one-sided (nothing is reflected from its back) and area emitters emit from their front side
only.
"""
import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .accel import nearest_hits
from .environment import environment_radiance
from .geometry import unit_normals
from .parallel import over_threads
from .texture import TextureArrays, texture_arrays, texture_value


class SceneArrays(NamedTuple):
    """The scene as the kernels take it."""

    triangles: np.ndarray  # (n, 3, 3)
    vertex_normals: np.ndarray  # (n, 3, 3) shading normals at the corners
    face_normals: np.ndarray  # (n, 3) unit geometric normals
    tri_material: np.ndarray  # (n,)
    tri_emitter: np.ndarray  # (n,) emitter id, -1 where the triangle does not emit
    reflectance: np.ndarray  # (materials, 3)
    twosided: np.ndarray  # (materials,)
    emitter_radiance: np.ndarray  # (emitters, 3)
    material_texture: np.ndarray  # (materials,) index into the `TextureArrays`, -1 for none
    tri_uv: np.ndarray  # (n, 3, 2) the corners' uv (a placeholder when no material has a texture)


class SurfaceArrays(NamedTuple):
    """What the surface interaction alone reads besides the `SceneArrays`: how the surface looks (its textures,
    the material seen from behind) and whether the emitters it sees directly are hidden."""

    textures: TextureArrays
    back_material: np.ndarray  # (materials,) the material seen from behind, -1 where it is the same
    hide_emitters: bool  # the environment seen directly is black (Mitsuba's integrator option; `camera_hits`
    # has passed the camera rays through emitting shapes)


def scene_arrays(scene):
    """The `SceneArrays` of a `Scene` (unit face normals computed here, once per render) and its
    `SurfaceArrays`."""
    uv = scene.tri_uv if scene.tri_uv is not None else np.zeros((1, 3, 2))
    return SceneArrays(scene.triangles, scene.vertex_normals, unit_normals(scene.triangles), scene.tri_material,
                       scene.tri_emitter, scene.reflectance, scene.twosided, scene.emitter_radiance,
                       scene.material_texture, uv), \
        SurfaceArrays(texture_arrays(scene.textures), scene.back_material, bool(scene.hide_emitters))


class Interactions(NamedTuple):
    """Surface interactions of a batch of camera samples; `material` is -1 where nothing is reflected (a miss or
    the back of a one-sided surface)."""

    triangle: np.ndarray  # (m,) scene triangle hit, -1 on a miss
    emitted: np.ndarray  # (m, 3) emitted radiance seen directly
    position: np.ndarray  # (m, 3)
    normal: np.ndarray  # (m, 3) shading normal on the camera's side
    material: np.ndarray  # (m,) int32
    albedo: np.ndarray  # (m, 3) diffuse reflectance at the point


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def _surface(geom, sf, es, prim, b1, b2, dirs, first, end, out):
    """Interactions first..end-1 into `out`, the zeroed (emitted, position, normal, material, albedo) arrays
    (serial, without Numba's allocator and reference counts: `surface_interactions` runs it over the threads)."""
    triangles, vnormals, tri_mat, tri_emit = geom.triangles, geom.vertex_normals, geom.tri_material, geom.tri_emitter
    twosided, radiance = geom.twosided, geom.emitter_radiance
    emitted, pos, nrm, mat, albedo = out
    scale = es.env_scale
    sky = (scale[0] != 0.0 or scale[1] != 0.0 or scale[2] != 0.0) and not sf.hide_emitters
    for i in range(first, end):
        tri = prim[i]
        if tri < 0:
            if sky:
                l0, l1, l2 = environment_radiance(es, dirs[i, 0], dirs[i, 1], dirs[i, 2])
                emitted[i, 0], emitted[i, 1], emitted[i, 2] = l0 * scale[0], l1 * scale[1], l2 * scale[2]
            continue
        c1, c2 = b1[i], b2[i]
        c0 = 1.0 - c1 - c2
        sx = c0 * vnormals[tri, 0, 0] + c1 * vnormals[tri, 1, 0] + c2 * vnormals[tri, 2, 0]
        sy = c0 * vnormals[tri, 0, 1] + c1 * vnormals[tri, 1, 1] + c2 * vnormals[tri, 2, 1]
        sz = c0 * vnormals[tri, 0, 2] + c1 * vnormals[tri, 1, 2] + c2 * vnormals[tri, 2, 2]
        inv = 1.0 / math.sqrt(sx * sx + sy * sy + sz * sz)
        sx, sy, sz = sx * inv, sy * inv, sz * inv
        cos_i = -(sx * dirs[i, 0] + sy * dirs[i, 1] + sz * dirs[i, 2])
        em = tri_emit[tri]
        if em >= 0 and cos_i > 0.0:
            for k in range(3):
                emitted[i, k] = radiance[em, k]
        m = tri_mat[tri]
        if cos_i <= 0.0:
            if not twosided[m]:
                continue
            sx, sy, sz = -sx, -sy, -sz
            if sf.back_material[m] >= 0:  # a two-sided material with another seen from behind
                m = sf.back_material[m]
        for k in range(3):
            pos[i, k] = c0 * triangles[tri, 0, k] + c1 * triangles[tri, 1, k] + c2 * triangles[tri, 2, k]
        nrm[i, 0], nrm[i, 1], nrm[i, 2] = sx, sy, sz
        mat[i] = m
        t = geom.material_texture[m]
        if t < 0:
            for k in range(3):
                albedo[i, k] = geom.reflectance[m, k]
        else:
            uv = geom.tri_uv
            u = c0 * uv[tri, 0, 0] + c1 * uv[tri, 1, 0] + c2 * uv[tri, 2, 0]
            v = c0 * uv[tri, 0, 1] + c1 * uv[tri, 1, 1] + c2 * uv[tri, 2, 1]
            albedo[i, 0], albedo[i, 1], albedo[i, 2] = texture_value(sf.textures, t, u, v)


def camera_hits(bvh, tri_emitter, hide_emitters, org, dirs, tmin, tmax):
    """The nearest hits of camera rays, as `accel.nearest_hits` returns them (scene triangle or -1, t, b1, b2,
    node and triangle tests). With `hide_emitters`, a ray that meets an emitting shape is traced on from there,
    until it meets a shape that does not emit or nothing; its tests add up."""
    prim, t, b1, b2, n_node, n_tri = nearest_hits(bvh, org, dirs, tmin, tmax)
    hidden = np.flatnonzero(prim >= 0) if hide_emitters else np.empty(0, np.int64)
    while True:
        hidden = hidden[(prim[hidden] >= 0) & (tri_emitter[np.maximum(prim[hidden], 0)] >= 0)]
        if len(hidden) == 0:
            break
        # each pass starts a billionth of the distance beyond the last hit (t rounded down would meet the same
        # triangle again), so every ray passes each emitting shape once and the loop ends
        past = t[hidden] * (1.0 + 1e-9)
        p2, t2, c1, c2, k_node, k_tri = nearest_hits(bvh, org[hidden], dirs[hidden], past, tmax[hidden])
        prim[hidden], t[hidden], b1[hidden], b2[hidden] = p2, t2, c1, c2
        n_node[hidden] += k_node
        n_tri[hidden] += k_tri
    return prim, t, b1, b2, n_node, n_tri


def surface_interactions(geom, surface, es, prim, b1, b2, dirs):
    """`Interactions` of camera rays with directions `dirs` that hit triangles `prim` (-1: a miss) at barycentrics
    (b1, b2); `surface` is the scene's `SurfaceArrays`, `es` its `EmitterArrays` (for the environment)."""
    n = len(prim)
    out = (np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3)), np.full(n, -1, np.int32), np.zeros((n, 3)))
    over_threads(lambda _, first, end: _surface(geom, surface, es, prim, b1, b2, dirs, first, end, out), n)
    return Interactions(prim, *out)
