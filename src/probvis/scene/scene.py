"""The scene as flat arrays: triangles, materials, emitters and a camera (with its film's resolution)."""
import dataclasses
import warnings
from dataclasses import dataclass, field

import numpy as np

from ..errors import ProbvisError
from ..settings import RenderSettings
from ..voxels import bounds

from . import transform as tf
from .mesh_geometry import angle_weighted_normals, face_geometry
from .sensor import Camera, camera_problem

MAX_COORDINATE = 1e30  # a position beyond this is refused: squared distances would overflow
RAY_OFFSET = 1e-9  # a shadow ray leaves its surface this far, times 1 + the point's largest coordinate
OFFSET_SHARE = 1e-4  # a scene whose largest offset exceeds this share of its extent is warned about
MAX_EMISSION = 1e30  # radiance, intensity or scale: beyond, power sums overflow
EMITTER_AREA, EMITTER_POINT, EMITTER_SPOT, EMITTER_DIRECTIONAL, EMITTER_ENVIRONMENT = 0, 1, 2, 3, 4


@dataclass
class Environment:
    """Light from infinitely far away: Mitsuba's `envmap` (a latitude-longitude `image`, linear RGB, rows from
    the +y pole down) or `constant` (`constant` is True and the image one colour). `to_world` is the rotation
    from the map's frame to the world; the emitter's radiance row holds the `scale`."""

    image: np.ndarray  # (h, w, 3)
    to_world: np.ndarray  # (3, 3)
    constant: bool = False
    mis_compensation: bool = False  # sampled by luminance minus its mean (`environment.sampling_luminance`)


@dataclass
class ShapeInfo:
    name: str
    kind: str
    first_triangle: int
    n_triangles: int
    emitter: int  # -1 when the shape does not emit
    lo: np.ndarray = field(default_factory=lambda: np.zeros(3), compare=False)  # the box of its vertices in world
    hi: np.ndarray = field(default_factory=lambda: np.zeros(3), compare=False)  # space, as Mitsuba's shape bbox


@dataclass
class Scene:
    """Triangles (n, 3, 3) with per-vertex shading normals, a material and an emitter id per triangle."""

    triangles: np.ndarray
    vertex_normals: np.ndarray
    tri_material: np.ndarray
    tri_emitter: np.ndarray
    reflectance: np.ndarray  # (n_materials, 3)
    twosided: np.ndarray  # (n_materials,) bool
    emitter_radiance: np.ndarray  # (n_emitters, 3) radiance of an area emitter, intensity of a point or spot
    camera: Camera = None
    defaults: RenderSettings = RenderSettings()  # the settings the scene file declares (sampler, integrator)
    name: str = "scene"
    source: str = ""
    inputs: tuple = ()  # the files it was read from (the XML, meshes, images): no output may replace one
    parameters: tuple = ()  # the names -D sets: the scene file's <default>s, a built-in scene's parameters
    shapes: list = field(default_factory=list)
    dropped_degenerate: int = 0
    # emitters that are points, not shapes: per emitter its kind (EMITTER_AREA, _POINT, _SPOT), position, the
    # spot's unit axis and its cone (cos cutoff, cos beam width, cutoff angle, 1 / transition width)
    emitter_kind: np.ndarray = None
    emitter_position: np.ndarray = None
    emitter_axis: np.ndarray = None
    emitter_cone: np.ndarray = None
    environment: Environment = None  # the one environment emitter, if any (its id: emitter_kind == 4)
    # reflectance textures: material m's is textures[material_texture[m]] (-1: none, `reflectance` holds its
    # colour), looked up at the corners' uv `tri_uv` (n, 3, 2); None when no material has a texture
    textures: list = field(default_factory=list)
    material_texture: np.ndarray = None
    tri_uv: np.ndarray = None
    hide_emitters: bool = False  # the integrator's option: the camera sees through emitting shapes, the sky black
    # (n_materials,) the material seen from behind, where a two-sided one has another there (Mitsuba's twosided
    # with two BSDFs); -1 elsewhere
    back_material: np.ndarray = None

    def __post_init__(self):
        e = len(self.emitter_radiance)
        if self.material_texture is None:
            self.material_texture = np.full(len(self.reflectance), -1, np.int32)
        if self.back_material is None:
            self.back_material = np.full(len(self.reflectance), -1, np.int32)
        if self.emitter_kind is None:
            self.emitter_kind = np.zeros(e, np.int8)
            self.emitter_position = np.zeros((e, 3))
            self.emitter_axis = np.zeros((e, 3))
            self.emitter_cone = np.zeros((e, 4))

    @property
    def n_triangles(self):
        return len(self.triangles)

    @property
    def n_emitters(self):
        return len(self.emitter_radiance)

    def bounds(self):
        return bounds(self.triangles)

    def with_resolution(self, width=None, height=None):
        """A copy whose film has another size, uncropped, its declared field of view kept along its axis (geometry
        arrays are shared, not copied)."""
        if isinstance(width, (tuple, list, np.ndarray)):  # with_resolution((w, h)): the film's (w, h) whole
            raise ProbvisError(f"with_resolution takes the width and height as two arguments, got {width!r}: "
                               "with_resolution(w, h)")
        cam = self.camera
        fw, fh = cam.film_width or cam.width, cam.film_height or cam.height
        if (fw, fh, cam.crop_x, cam.crop_y) != (cam.width, cam.height, 0, 0):  # the user set a crop window
            warnings.warn(f"scene '{self.name}': the new resolution renders the whole view, not the film's crop "
                          f"window ({cam.width}x{cam.height} at ({cam.crop_x}, {cam.crop_y}) of {fw}x{fh})",
                          stacklevel=3)
        cam = cam.resized(cam.width if width is None else width, cam.height if height is None else height)
        out = dataclasses.replace(self, camera=cam)
        out.validate_camera()
        return out

    def read_only(self):
        """A copy whose arrays (the camera's and the environment's too) are read-only views of these: what a
        plug-in estimator is handed, so that a write fails in its own code instead of changing the caller's scene
        for later renders."""
        def frozen(record):
            if record is None:
                return None
            views = {}
            for f in dataclasses.fields(record):
                value = getattr(record, f.name)
                if isinstance(value, np.ndarray):
                    views[f.name] = value.view()
                    views[f.name].flags.writeable = False
            return dataclasses.replace(record, **views)

        return dataclasses.replace(frozen(self), camera=frozen(self.camera), environment=frozen(self.environment))

    def content_hash(self):
        """SHA-256 of the scene: geometry, materials, emitters and camera (including the resolution), not the
        render settings. Used to cache renders across runs."""
        import hashlib

        h = hashlib.sha256()
        for a in (self.triangles, self.vertex_normals, self.tri_material, self.tri_emitter, self.reflectance,
                  self.twosided, self.emitter_radiance, self.camera.to_world, self.emitter_kind,
                  self.emitter_position, self.emitter_axis, self.emitter_cone,
                  *((self.environment.image, self.environment.to_world) if self.environment else ()),
                  self.material_texture, *((self.tri_uv,) if self.tri_uv is not None else ()),
                  *(a for t in self.textures for a in (t.to_uv, t.image if t.image is not None else t.colours,
                                                       np.array([t.kind, t.wrap, t.bilinear])))):
            a = np.ascontiguousarray(a)
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(a.tobytes())
        c = self.camera
        h.update(repr((float(c.fov_x), int(c.width), int(c.height), float(c.near_clip), float(c.far_clip),
                       c.film_size, c.crop_x, c.crop_y, c.principal_x, c.principal_y, c.aperture_radius,
                       c.focus_distance, c.rfilter, c.filter_radius, c.filter_stddev)
                      + ((c.filter_b, c.filter_c) if c.rfilter == "mitchell" else ())).encode())
        if self.hide_emitters:
            h.update(b"hide_emitters")
        if np.any(np.asarray(self.back_material) >= 0):
            h.update(np.ascontiguousarray(self.back_material, np.int64).tobytes())
        return h.hexdigest()

    def validate(self):
        """A `Scene` given to a render, possibly changed since it was built: `scene_checks.check_scene`."""
        from .scene_checks import check_scene

        check_scene(self)

    def validate_camera(self):
        if problem := camera_problem(self.camera):
            raise ProbvisError(problem)
        if self.environment is None and len(self.triangles):  # clip planes that leave nothing to see: black
            c = self.camera
            lo, hi = self.bounds()
            corners = np.array([[(lo, hi)[(k >> a) & 1][a] for a in range(3)] for k in range(8)])
            axis = c.to_world[:3, 2] / np.linalg.norm(c.to_world[:3, 2])
            depth = (corners - c.to_world[:3, 3]) @ axis  # the clip planes cut along the view axis
            nearest, farthest = float(depth.min()), float(depth.max())
            if c.near_clip > farthest or c.far_clip < nearest:
                raise ProbvisError(f"the clip range [{c.near_clip:g}, {c.far_clip:g}] (near_clip, far_clip) leaves "
                                   f"out the whole scene, {nearest:g} to {farthest:g} deep in the camera's view: "
                                   "the image would be black")


class SceneBuilder:
    """Collects shapes with materials and emitters, then produces a validated `Scene`."""

    def __init__(self, name="scene", source=""):
        self.name, self.source = name, source
        self.inputs = ()
        self.parameters = ()  # `Scene.parameters`
        self._tris, self._normals, self._mat, self._emit, self._uv = [], [], [], [], []
        self._materials = {}  # (reflectance, twosided, texture index, back material or -1) -> id
        self.textures = []
        self.emitter_radiance = []
        self.deltas = {}  # emitter id -> (kind, position, axis, cone) of point and spot emitters
        self.environment = None
        self.shapes = []
        self.dropped = 0
        self._n = 0
        self.hide_emitters = False  # the integrator's option (`Scene.hide_emitters`)

    def material(self, reflectance, twosided=False, texture=None, back=None):
        """The id of a diffuse material: its `reflectance`, or a `Texture` (reflectance then its mean); `back`, a
        (reflectance, texture) pair, is another material seen from behind (two-sided)."""
        back_id = -1 if back is None else self.material(back[0], True, back[1])
        t = -1
        if texture is not None:
            t = next((k for k, x in enumerate(self.textures) if x.same_as(texture)), len(self.textures))
            if t == len(self.textures):
                self.textures.append(texture)
            reflectance = texture.mean()
        key = (tuple(float(x) for x in np.broadcast_to(reflectance, 3)), bool(twosided or back is not None), t, back_id)
        if key not in self._materials:
            self._materials[key] = len(self._materials)
        return self._materials[key]

    def add_mesh(self, name, kind, vertices, faces, to_world=None, material=None, radiance=None,
                 face_normals=True, vertex_normals=None, flip_normals=False, uv=None):
        """Add a triangle mesh in object space; `to_world` is applied here; `uv` (per vertex, or per face
        corner as (faces, 3, 2)) default to the barycentric coordinates, as Mitsuba's. Returns the number of
        triangles kept."""
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces, dtype=np.int64)
        if not np.all(np.isfinite(v)):
            raise ProbvisError(f"shape '{name}' has NaN or infinite vertex coordinates")
        if f.size and (f.min() < 0 or f.max() >= len(v)):
            raise ProbvisError(f"shape '{name}' has face indices out of range")
        m = np.eye(4) if to_world is None else np.asarray(to_world, dtype=np.float64)
        if not np.all(np.isfinite(m)):
            raise ProbvisError(f"shape '{name}' has a non-finite to_world transform")
        with np.errstate(over="ignore", invalid="ignore"):  # beyond the limit: refused below, or unused
            wv = tf.apply_points(m, v)
        if not np.all(np.abs(wv) <= MAX_COORDINATE) and f.size:  # the vertices no face uses do not count (Mitsuba
            used = np.zeros(len(wv), bool)  # renders them away): given a used one's place, out of the bounds
            used[f.ravel()] = True
            wv = np.where(used[:, None], wv, wv[used][0])
        if not np.all(np.abs(wv) <= MAX_COORDINATE):
            raise ProbvisError(f"shape '{name}' has vertices beyond ±{MAX_COORDINATE:g} once transformed (or not a "
                               "number): rescale the scene")
        if flip_normals:
            f = f[:, ::-1]
        tris, cross, area2, keep = face_geometry(wv, f)
        lo, hi = bounds(wv) if len(wv) else (np.zeros(3), np.zeros(3))
        self.dropped += int((~keep).sum())
        if not keep.all():
            tris, f, cross, area2 = tris[keep], f[keep], cross[keep], area2[keep]
        if uv is None:  # the corners' barycentric coordinates, in the file's vertex order
            corners = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
            self._uv.append(np.broadcast_to(corners[::-1] if flip_normals else corners, (len(f), 3, 2)))
        elif np.ndim(uv) == 3:  # per corner, one row per face as given
            self._uv.append(np.asarray(uv, dtype=np.float64)[keep][:, ::-1] if flip_normals else
                            np.asarray(uv, dtype=np.float64)[keep])
        else:
            self._uv.append(np.asarray(uv, dtype=np.float64)[f])
        fn = cross / area2[:, None]
        if face_normals or len(tris) == 0:
            normals = np.repeat(fn[:, None, :], 3, axis=1)
        else:
            if vertex_normals is None:
                vn = angle_weighted_normals(wv, f, fn)
            else:
                vn = tf.apply_normals(m, np.asarray(vertex_normals, dtype=np.float64))
                if flip_normals:
                    vn = -vn
            normals = vn[f]
            if radiance is not None:
                tris, normals = self._emit_towards_normals(tris, normals, fn)
        if material is None:
            material = self.material((0.5, 0.5, 0.5))  # Mitsuba's default BSDF
        emitter = -1
        if radiance is not None and len(tris):  # a shape without area emits nothing: no emitter
            emitter = len(self.emitter_radiance)
            self.emitter_radiance.append(np.asarray(radiance, dtype=np.float64) * np.ones(3))
        self.shapes.append(ShapeInfo(name, kind, self._n, len(tris), emitter, lo, hi))
        self._tris.append(tris)
        self._normals.append(normals)
        self._mat.append(np.full(len(tris), material, dtype=np.int32))
        self._emit.append(np.full(len(tris), emitter, dtype=np.int32))
        self._n += len(tris)
        return len(tris)

    def _emit_towards_normals(self, tris, normals, fn):
        """An emitting mesh's triangles whose vertex normals point against their winding (an exporter that
        reversed the faces and kept the normals), reversed: Mitsuba emits towards the shading normals, both into
        the scene and as seen directly, and probvis's emitter sampling takes a triangle's face as its front. The
        sum of the three normals decides a triangle; the corners' uv, already appended, follow."""
        back = np.einsum("tkj,tj->t", normals, fn) < 0.0
        if not back.any():
            return tris, normals
        tris, normals, uv = tris.copy(), normals.copy(), np.array(self._uv[-1])
        for a in (tris, normals, uv):
            a[back] = a[back][:, ::-1]
        self._uv[-1] = uv
        return tris, normals

    def add_point_emitter(self, intensity, position, axis=None, cutoff_deg=None, beam_deg=None):
        """A point light, or with an `axis` and angles a spot light (Mitsuba's linear falloff in angle between
        the beam width and the cutoff). Returns its emitter id."""
        e = len(self.emitter_radiance)
        self.emitter_radiance.append(np.asarray(intensity, dtype=np.float64) * np.ones(3))
        if axis is None:
            self.deltas[e] = (EMITTER_POINT, np.asarray(position, float), np.zeros(3), np.zeros(4))
        else:
            c, b = np.radians(cutoff_deg), np.radians(beam_deg)
            cone = np.array([np.cos(c), np.cos(b), c, 1.0 / (c - b) if c > b else np.inf])
            self.deltas[e] = (EMITTER_SPOT, np.asarray(position, float), np.asarray(axis, float) /
                              np.linalg.norm(axis), cone)
        return e

    def add_directional_emitter(self, irradiance, direction):
        """A directional light: `irradiance` on a surface facing it, light travelling along `direction`."""
        e = len(self.emitter_radiance)
        self.emitter_radiance.append(np.asarray(irradiance, dtype=np.float64) * np.ones(3))
        d = np.asarray(direction, float)
        self.deltas[e] = (EMITTER_DIRECTIONAL, np.zeros(3), d / np.linalg.norm(d), np.zeros(4))
        return e

    def add_environment(self, image, to_world=None, scale=1.0, constant=False, mis_compensation=False):
        """The scene's environment emitter (at most one): a latitude-longitude `image` (h >= 2 rows, w >= 1
        columns, linear RGB) times `scale` (a number or RGB), rotated by `to_world` (4x4 or 3x3); sampled by its
        luminance less the mean with `mis_compensation`, as Mitsuba's envmap."""
        if self.environment is not None:
            raise ProbvisError("only one environment emitter (envmap or constant) can be specified per scene")
        img = np.asarray(image, dtype=np.float64)
        if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] < 2 or img.shape[1] < 1:
            raise ProbvisError(f"an environment map needs at least 2 rows and 1 column of RGB, got {img.shape}")
        if not np.all(np.isfinite(img)):
            raise ProbvisError("the environment map has NaN or infinite pixels")
        m = np.eye(3) if to_world is None else np.asarray(to_world, dtype=np.float64)[:3, :3]
        e = len(self.emitter_radiance)
        self.emitter_radiance.append(np.ones(3) * np.asarray(scale, dtype=np.float64))
        self.deltas[e] = (EMITTER_ENVIRONMENT, np.zeros(3), np.zeros(3), np.zeros(4))
        self.environment = Environment(np.ascontiguousarray(img), m, constant, bool(mis_compensation))
        return e

    def build(self, camera, defaults=RenderSettings()):
        """The `Scene`; `defaults` are the render settings the scene declares."""
        if self._n == 0:
            seen = " (an environment alone is a background with nothing for it to light, which probvis does not " \
                   "render: add a shape)" if self.environment is not None else \
                ": nothing to light, the image would be black (as Mitsuba renders it): add a shape"
            raise ProbvisError(f"scene '{self.name}' contains no (non-degenerate) triangles{seen}")
        if not self.emitter_radiance:
            raise ProbvisError(f"scene '{self.name}' has no emitter: add an area emitter to a shape, or a point, "
                               "spot, directional, envmap or constant emitter")
        e = len(self.emitter_radiance)
        kind, position, axis, cone = np.zeros(e, np.int8), np.zeros((e, 3)), np.zeros((e, 3)), np.zeros((e, 4))
        for k, (kd, pos, ax, cn) in self.deltas.items():
            kind[k], position[k], axis[k], cone[k] = kd, pos, ax, cn
        mats = sorted(self._materials.items(), key=lambda kv: kv[1])
        material_texture = np.array([k[2] for k, _ in mats], np.int32)
        back_material = np.array([k[3] for k, _ in mats], np.int32)
        scene = Scene(
            triangles=_joined(self._tris),
            vertex_normals=_joined(self._normals),
            tri_material=_joined(self._mat),
            tri_emitter=_joined(self._emit),
            reflectance=np.array([k[0] for k, _ in mats], dtype=np.float64).reshape(-1, 3),
            twosided=np.array([k[1] for k, _ in mats], dtype=np.bool_),
            emitter_radiance=np.array(self.emitter_radiance, dtype=np.float64).reshape(-1, 3),
            emitter_kind=kind, emitter_position=position, emitter_axis=axis, emitter_cone=cone,
            environment=self.environment,
            textures=self.textures,
            material_texture=material_texture,
            back_material=back_material,
            tri_uv=_joined(self._uv) if self.textures else None,
            camera=camera,
            defaults=defaults.validate(),
            name=self.name,
            source=self.source,
            inputs=self.inputs,
            parameters=self.parameters,
            shapes=self.shapes,
            dropped_degenerate=self.dropped,
            hide_emitters=self.hide_emitters,
        )
        scene.validate_camera()
        from .scene_checks import warn_of_offsets  # the checks' module reads this one's records

        warn_of_offsets(scene)
        return scene


def _joined(parts):
    """The shapes' arrays as one contiguous array (a single shape's own array, not a copy)."""
    return np.ascontiguousarray(parts[0] if len(parts) == 1 else np.concatenate(parts))
