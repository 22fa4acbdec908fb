"""The checks of a `Scene` handed to a render: the API's Scene is a mutable record, and a field changed since the
scene was built (a camera of None, NaN normals, a texture index past the textures) would otherwise surface as a
TypeError, a black image or an out-of-bounds read in a kernel."""
import warnings
from pathlib import Path

import numpy as np

from ..errors import ProbvisError
from ..settings import RenderSettings
from ..texture import BITMAP, CHECKERBOARD, WRAP_MODES, Texture
from .scene import (EMITTER_AREA, EMITTER_DIRECTIONAL, EMITTER_ENVIRONMENT, EMITTER_POINT, EMITTER_SPOT,
                    MAX_COORDINATE, MAX_EMISSION, OFFSET_SHARE, RAY_OFFSET, Environment, ShapeInfo)
from .sensor import Camera
from .shapes import MAX_UV



def check_scene(scene):
    """ProbvisError naming the first of the scene's records and arrays that is not of the type and shape the render
    reads, not finite, or an index out of range; then the camera's own checks."""
    if not isinstance(scene.camera, Camera):
        raise ProbvisError(f"scene.camera must be a Camera, got {type(scene.camera).__name__}")
    if not isinstance(scene.defaults, RenderSettings):
        raise ProbvisError(f"scene.defaults must be a RenderSettings, got {type(scene.defaults).__name__}")
    for name, kind in (("shapes", ShapeInfo), ("textures", Texture)):
        items = getattr(scene, name)
        if not isinstance(items, list) or not all(isinstance(x, kind) for x in items):
            raise ProbvisError(f"scene.{name} must be a list of {kind.__name__}")
    if scene.environment is not None and not isinstance(scene.environment, Environment):
        raise ProbvisError(f"scene.environment must be an Environment or None, got "
                           f"{type(scene.environment).__name__}")
    if not isinstance(scene.hide_emitters, (bool, np.bool_)):
        raise ProbvisError(f"scene.hide_emitters must be True or False, got {scene.hide_emitters!r}")
    for name in ("name", "source"):
        if not isinstance(getattr(scene, name), str):
            raise ProbvisError(f"scene.{name} must be a string, got {type(getattr(scene, name)).__name__}")
    if not isinstance(scene.inputs, tuple) or not all(isinstance(p, (str, Path)) for p in scene.inputs):
        raise ProbvisError("scene.inputs must be a tuple of the paths the scene was read from")
    for k, t in enumerate(scene.textures):
        if not (t.kind in (BITMAP, CHECKERBOARD) and t.wrap in WRAP_MODES.values() and _fine(t.to_uv, (2, 3))
                and (_fine(t.image, (None, None, 3)) and min(t.image.shape[:2]) >= 1 if t.kind == BITMAP
                     else _fine(t.colours, (2, 3)))):
            raise ProbvisError(f"scene.textures[{k}] must be a BITMAP with a finite (h, w, 3) image of at least one "
                               "pixel or a CHECKERBOARD with finite (2, 3) colours, with a known wrap mode and a "
                               "finite (2, 3) to_uv")
    env = scene.environment
    if env is not None and not (_fine(env.image, (None, None, 3)) and env.image.shape[0] >= 2
                                and env.image.shape[1] >= 1 and np.all(env.image >= 0)
                                and np.all(env.image <= MAX_EMISSION) and _fine(env.to_world, (3, 3))
                                and np.allclose(env.to_world @ env.to_world.T, np.eye(3), atol=1e-6)):
        raise ProbvisError(f"scene.environment must hold a (h >= 2, w >= 1, 3) image of values from 0 to "
                           f"{MAX_EMISSION:g} and a rotation (3, 3) to_world")
    if (env is not None) != bool(np.any(np.asarray(scene.emitter_kind) == EMITTER_ENVIRONMENT)):
        raise ProbvisError("scene.environment must be set exactly when an emitter's kind is EMITTER_ENVIRONMENT")
    n, m, e = (len(a) if isinstance(a, np.ndarray) and a.ndim else "n"  # not an array: refused below, first
               for a in (scene.triangles, scene.reflectance, scene.emitter_radiance))
    for name, shape, kinds in (("triangles", (n, 3, 3), "f"), ("vertex_normals", (n, 3, 3), "f"),
                               ("tri_material", (n,), "iu"), ("tri_emitter", (n,), "iu"),
                               ("reflectance", (m, 3), "f"), ("twosided", (m,), "b"),
                               ("material_texture", (m,), "iu"), ("back_material", (m,), "iu"),
                               ("emitter_radiance", (e, 3), "f"),
                               ("emitter_kind", (e,), "iu"), ("emitter_position", (e, 3), "f"),
                               ("emitter_axis", (e, 3), "f"), ("emitter_cone", (e, 4), "f"),
                               *((("tri_uv", (n, 3, 2), "f"),) if scene.tri_uv is not None else ())):
        a = getattr(scene, name)
        base, row = (("emitter_radiance", "emitter") if name.startswith("emitter") else
                     ("reflectance", "material") if name in ("reflectance", "twosided", "material_texture",
                                                             "back_material") else
                     ("triangles", "triangle"))
        if (isinstance(a, np.ndarray) and a.ndim == len(shape) and a.shape[1:] == shape[1:] and a.shape[0] != shape[0]
                and name != base):  # one of a family of arrays changed alone
            raise ProbvisError(f"scene.{name} has {a.shape[0]} rows where scene.{base} has {shape[0]}: the arrays "
                               f"with a row per {row} change together")
        if not isinstance(a, np.ndarray) or a.shape != shape or a.dtype.kind not in kinds or not a.dtype.isnative \
                or (kinds == "f" and a.dtype.itemsize not in (4, 8)) or a.dtype == np.uint64:
            # half, long double, other byte order: no kernel; uint64 does not mix with NumPy's signed indices
            raise ProbvisError(f"scene.{name} must be a {' x '.join(map(str, shape))} array of "
                               f"{dict(f='floats (32 or 64 bits)', iu='integers (not uint64)', b='booleans')[kinds]} "
                               f"in the machine's byte order, got {getattr(a, 'shape', type(a).__name__)} "
                               f"{getattr(a, 'dtype', '')}".rstrip()
                               + (f": use scene.{name}.astype(np.int32)"
                                  if kinds == "iu" and getattr(a, "dtype", None) == np.uint64 else ""))
    extent = {}  # each array's min and max: NaN or ±inf reach one of them
    for name in ("triangles", "vertex_normals", "emitter_radiance", "emitter_position", "emitter_axis",
                 "emitter_cone"):
        a = getattr(scene, name)
        extent[name] = (float(a.min()), float(a.max())) if a.size else (0.0, 0.0)
        if not np.all(np.isfinite(extent[name])):
            raise ProbvisError(f"scene.{name} must be finite (it holds NaN or infinite values)")
    for name in ("triangles", "emitter_position"):  # as the scene reader bounds them: beyond, products overflow
        if max(-extent[name][0], extent[name][1]) > MAX_COORDINATE:
            raise ProbvisError(f"scene.{name} must lie within ±{MAX_COORDINATE:g}: rescale the scene")
    aimed = np.isin(scene.emitter_kind, (EMITTER_SPOT, EMITTER_DIRECTIONAL))
    if not np.all(np.abs(scene.emitter_axis[aimed]).max(axis=-1, initial=0.0) > 0.0):
        raise ProbvisError("scene.emitter_axis must not be zero for a spot or directional light (it is the "
                           "direction the light points to)")
    kinds = (EMITTER_AREA, EMITTER_POINT, EMITTER_SPOT, EMITTER_DIRECTIONAL, EMITTER_ENVIRONMENT)
    if not (np.all(np.isin(scene.emitter_kind, kinds)) and scene.material_texture.min(initial=-1) >= -1
            and scene.material_texture.max(initial=-1) < len(scene.textures)):
        raise ProbvisError("scene.emitter_kind must hold EMITTER_* kinds and scene.material_texture index "
                           "scene.textures (-1: none)")
    if not (scene.back_material.min(initial=-1) >= -1 and scene.back_material.max(initial=-1) < m):
        raise ProbvisError("scene.back_material must index scene.reflectance (-1: the same material from behind)")
    if scene.textures and scene.tri_uv is None:
        raise ProbvisError("scene.tri_uv must hold the corners' uv of a scene with textures")
    if scene.tri_uv is not None and not np.all(np.abs(scene.tri_uv) <= MAX_UV):
        raise ProbvisError(f"scene.tri_uv must be finite and within ±{MAX_UV:g}")
    vn = scene.vertex_normals  # per component: a reduction over the last axis of 3 is six times slower
    if not np.all((vn[..., 0] != 0.0) | (vn[..., 1] != 0.0) | (vn[..., 2] != 0.0)):
        raise ProbvisError("scene.vertex_normals must not be zero")
    if not np.all(scene.emitter_radiance <= MAX_EMISSION):
        raise ProbvisError(f"scene.emitter_radiance must be at most {MAX_EMISSION:g}")
    if any(not (0 <= s.first_triangle and s.n_triangles >= 0 and s.first_triangle + s.n_triangles <= n)
           for s in scene.shapes):
        raise ProbvisError("scene.shapes' first_triangle and n_triangles must lie within scene.triangles")
    plain = scene.reflectance[np.asarray(scene.material_texture) < 0]  # a textured one holds its texture's mean
    if not (np.all((plain >= 0.0) & (plain <= 1.0)) and np.all(scene.emitter_radiance >= 0.0)):
        raise ProbvisError("scene.reflectance must be within [0, 1] and scene.emitter_radiance non-negative")
    if n and not (0 <= scene.tri_material.min() and scene.tri_material.max() < m
                  and -1 <= scene.tri_emitter.min() and scene.tri_emitter.max() < e):
        raise ProbvisError("scene.tri_material and scene.tri_emitter must index scene.reflectance and "
                           "scene.emitter_radiance (-1: no emitter)")
    scene.validate_camera()


def _fine(a, shape):
    """Whether `a` is a finite numeric array of `shape` (None: any length)."""
    return (isinstance(a, np.ndarray) and a.dtype.kind in "fiu" and a.ndim == len(shape)
            and all(want is None or got == want for got, want in zip(a.shape, shape)) and bool(np.all(np.isfinite(a))))


def warn_of_offsets(scene):
    """A warning where shadow rays' offsets from their surfaces (RAY_OFFSET, as Mitsuba's ray epsilon: absolute
    near the origin, relative far from it) are a noticeable share of the scene: a scene far smaller than a unit,
    or far from the origin for its size, can lose small shadows without it."""
    lo, hi = np.min([s.lo for s in scene.shapes], axis=0), np.max([s.hi for s in scene.shapes], axis=0)
    extent = float((hi - lo).max())
    offset = RAY_OFFSET * (1.0 + float(max(np.abs(lo).max(), np.abs(hi).max())))
    if offset > OFFSET_SHARE * extent:
        warnings.warn(f"scene '{scene.name}' spans {extent:g} units with coordinates up to "
                      f"{offset / RAY_OFFSET - 1:g}: shadow rays leave their surfaces up to {offset:g} away "
                      f"({offset / max(extent, 1e-300):.2%} of the scene), which can lose small shadows; scale the "
                      "scene nearer to unit size, or move it nearer the origin", stacklevel=4)
