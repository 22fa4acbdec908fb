"""Triangle meshes for the shapes probvis knows: Mitsuba's rectangle and cube, a tessellated sphere, mesh files."""
import io
import re
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..errors import ProbvisError, missing_file
from .obj import read_obj
from .ply import read_ply


class MeshData(NamedTuple):
    """A mesh as read from a file: vertices, faces, and per-vertex normals and uv where the file has them."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray = None
    uv: np.ndarray = None


def rectangle():
    """Mitsuba's rectangle: [-1, 1]^2 in the z = 0 plane, front side +z."""
    v = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    f = np.array([[0, 1, 2], [2, 3, 0]], dtype=np.int64)
    return v, f


def cube():
    """Mitsuba's cube: [-1, 1]^3 with outward-facing triangles (two per face)."""
    v, faces = [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            u_ax, v_ax = (axis + 1) % 3, (axis + 2) % 3
            base = len(v)
            for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                p = [0.0, 0.0, 0.0]
                p[axis], p[u_ax], p[v_ax] = sign, a, b
                v.append(p)
            if sign > 0:
                faces += [[base, base + 1, base + 2], [base + 2, base + 3, base]]
            else:
                faces += [[base, base + 2, base + 1], [base + 2, base, base + 3]]
    return np.array(v), np.array(faces, dtype=np.int64)


def uv_sphere(rings=32, segments=64):
    """Unit sphere tessellated in latitude/longitude, outward winding, with its exact vertex normals."""
    theta = np.linspace(0.0, np.pi, rings + 1)
    phi = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta[1:-1], phi, indexing="ij")
    body = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1).reshape(-1, 3)
    v = np.vstack([[0.0, 0.0, 1.0], body, [0.0, 0.0, -1.0]])
    south = len(v) - 1
    faces = []

    def ring(i, j):
        return 1 + i * segments + (j % segments)

    for j in range(segments):
        faces.append([0, ring(0, j), ring(0, j + 1)])
        faces.append([south, ring(rings - 2, j + 1), ring(rings - 2, j)])
    for i in range(rings - 2):
        for j in range(segments):
            a, b, c, d = ring(i, j), ring(i + 1, j), ring(i + 1, j + 1), ring(i, j + 1)
            faces += [[a, b, c], [a, c, d]]
    return v, np.array(faces, dtype=np.int64), v.copy()


def analytic_uv(kind, corners):
    """Per-corner uv (n, 3, 2) of a tessellated `sphere`, `disk` or `cylinder` in object space, Mitsuba's
    parameterisations sampled at the corners: sphere (phi / 2 pi, theta / pi) about +z, disk (r, phi / 2 pi),
    cylinder (phi / 2 pi, z), phi from +x in [0, 2 pi). A triangle across the phi = 0 seam gets its small phi
    raised by 2 pi, and a corner on the axis (a pole, the disk's centre) the mean phi of the other two."""
    x, y, z = corners[..., 0], corners[..., 1], corners[..., 2]
    phi = np.arctan2(y, x) / (2 * np.pi) % 1.0
    on_axis = np.hypot(x, y) < 1e-12
    phi = np.where(on_axis, np.nan, phi)
    wrap = np.nanmax(phi, axis=1, keepdims=True) - np.nanmin(phi, axis=1, keepdims=True) > 0.5
    phi = np.where(wrap & (phi < 0.5), phi + 1.0, phi)
    phi = np.where(on_axis, np.nanmean(phi, axis=1, keepdims=True), phi)
    if kind == "sphere":
        return np.stack([phi, np.arccos(np.clip(z / np.linalg.norm(corners, axis=2), -1, 1)) / np.pi], -1)
    if kind == "disk":
        return np.stack([np.hypot(x, y), phi], -1)
    return np.stack([phi, z], -1)


def _obj_problem(path):
    """The first face of an OBJ file that a reader would misread, as 'file:line: ...' (None if none is): fewer
    than three vertices, or a vertex, texture coordinate or normal index of 0 or beyond those defined before it.
    Run on a file the reader rejected, or whose faces it did not all keep, or that has uv or normals."""
    counts = {"v": 0, "vt": 0, "vn": 0}  # defined so far: a negative index counts back from the face
    what = ("vertex", "texture coordinate", "normal")
    plural = {"vertex": "vertices", "texture coordinate": "texture coordinates", "normal": "normals"}
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            totals = {k: 0 for k in counts}  # in the whole file: a positive index may point forward
            for line in f:
                word = line.split(None, 1)[0] if line.strip() else ""
                if word in totals:
                    totals[word] += 1
            f.seek(0)
            for line_no, line in enumerate(f, 1):
                parts = line.split("#", 1)[0].split()
                if not parts:
                    continue
                if parts[0] in counts:
                    counts[parts[0]] += 1
                    need = 1 if parts[0] == "vt" else 3  # numbers a statement needs: vt u [v [w]], v/vn x y z
                    if len(parts) <= need:
                        return f"{path}:{line_no}: '{parts[0]}' needs {need} number{'s' * (need > 1)}: '{line.strip()}'"
                    try:
                        [float(x) for x in parts[1:need + 1]]
                    except ValueError:
                        return f"{path}:{line_no}: malformed '{parts[0]}' statement '{line.strip()}'"
                elif parts[0] == "f":
                    if len(parts) < 4:
                        return f"{path}:{line_no}: a face needs at least 3 vertices: '{line.strip()}'"
                    for item in parts[1:]:
                        fields = item.split("/")
                        if len(fields) > 3 or not fields[0]:
                            return f"{path}:{line_no}: malformed face '{line.strip()}'"
                        for kind, name, text in zip(("v", "vt", "vn"), what, fields):
                            if not text:
                                continue
                            try:
                                k = int(text)
                            except ValueError:
                                return f"{path}:{line_no}: malformed face '{line.strip()}'"
                            if k == 0:
                                return f"{path}:{line_no}: face index 0 is invalid (OBJ indices start at 1)"
                            if k > totals[kind]:
                                return (f"{path}:{line_no}: face refers to {name} {k}, but the file defines only "
                                        f"{totals[kind]} {plural[name]}")
                            if k < -counts[kind]:
                                return (f"{path}:{line_no}: face refers to {name} {k}, but only {counts[kind]} "
                                        f"{plural[name]} are defined before it")
    except OSError as exc:
        return f"cannot read mesh {path}: {exc.strerror or exc}"
    return None


OBJ_LINE_CHECK_BYTES = 32 << 20  # uv and normal indices are checked line by line in OBJ files up to this size


def _obj_checked(path, mesh):
    """`_obj_problem` of an OBJ that the reader read, where it may have misread: fewer triangles than face
    statements (a face dropped), or uv or normal indices, which the reader does not check (in files up to
    OBJ_LINE_CHECK_BYTES: a Python pass over a larger scan would cost more than reading it)."""
    data = path.read_bytes()
    faces = data.count(b"\nf ") + data.startswith(b"f ")
    kept = len(mesh.faces) if mesh is not None else 0
    if kept < faces or len(data) <= OBJ_LINE_CHECK_BYTES and (b"\nvt " in data or b"\nvn " in data):
        return _obj_problem(path)
    return None


MAX_MESH_BYTES = 8 << 30  # a mesh file larger than this is refused before reading
MAX_UV = 1e9  # a vertex's uv: beyond, a texture's coordinates lose all precision
# OBJ statements that group faces or name materials, which Mitsuba's reader ignores; given them, trimesh splits
# the mesh per material (a copy of every vertex per group), reorders faces by group and packs the uv into an atlas
_OBJ_GROUPING = re.compile(rb"(?m)^[ \t]*(?:usemtl|mtllib|g|o)\b[^\r\n]*")


def _ply_elements(path):
    """The element counts a PLY header declares ({"vertex": n, "face": m}); empty if it has none readable."""
    counts = {}
    try:
        with open(path, "rb") as fh:
            for _ in range(1000):
                line = fh.readline(1024).decode("ascii", "replace").split()
                if not line or line[0] == "end_header":
                    break
                if line[0] == "element" and len(line) == 3 and line[2].lstrip("-").isdigit():
                    counts[line[1]] = int(line[2])
    except OSError:
        return {}
    return counts


def _ply_truncated(path, declared, mesh):
    """A message if the PLY file holds fewer vertices or faces than its header declares (None otherwise)."""
    if not declared:
        return None
    if any(n < 0 for n in declared.values()):
        return f"mesh {path}: malformed PLY header (a negative element count: {declared})"
    got_v = 0 if mesh is None else len(getattr(mesh, "vertices", ()))
    got_f = 0 if mesh is None else len(getattr(mesh, "faces", ()))
    if got_v < declared.get("vertex", 0) or got_f < declared.get("face", 0) or mesh is None:
        return (f"mesh {path}: truncated or malformed PLY (its header declares {declared.get('vertex', 0):,} "
                f"vertices and {declared.get('face', 0):,} faces)")
    return None


def _read(path, fmt):
    """trimesh's reader of the file's type, straight into one mesh: (Trimesh, the file's vertex normals or None).
    An OBJ is read as Mitsuba does, one mesh in file order (grouping statements dropped); the readers' arrays go
    into the mesh directly (trimesh.load's scene round trip took five times longer on a large PLY and dropped
    the file's normals)."""
    import trimesh

    if fmt == "obj":
        from trimesh.exchange.obj import load_obj

        kwargs = load_obj(io.BytesIO(_OBJ_GROUPING.sub(b"", path.read_bytes())), maintain_order=True)
        parts = list(kwargs["geometry"].values()) if "geometry" in kwargs else [kwargs]
        if len(parts) != 1:
            return None, None
        kwargs = parts[0]
    else:
        from trimesh.exchange.ply import load_ply

        with open(path, "rb") as fh:
            kwargs = load_ply(fh)
    normals = kwargs.pop("vertex_normals", None)
    return trimesh.Trimesh(**kwargs, process=False, maintain_order=True), normals


def load_mesh(path, flip_tex_coords=None, fmt=None):
    """Read an OBJ or PLY file as `MeshData`, order preserved: by `read_obj` or `read_ply` where the file's
    layout allows, by trimesh's reader otherwise. `fmt` ("obj" or "ply", a scene's shape type; by default the
    file's extension) chooses the reader, as Mitsuba reads by the shape's type. Texture coordinates are flipped
    vertically (v -> 1 - v) by default for OBJ and not for PLY, as Mitsuba's `flip_tex_coords` defaults."""
    path = Path(path)
    fmt = fmt or path.suffix.lower().lstrip(".")
    if fmt not in ("obj", "ply"):
        raise ProbvisError(f"mesh {path}: not an .obj or .ply file (a scene's shape type names the format)")
    if not path.exists():
        raise ProbvisError(missing_file(path, "mesh file"))
    if not path.is_file():
        raise ProbvisError(f"mesh {path} is not a regular file")
    if path.stat().st_size > MAX_MESH_BYTES:
        raise ProbvisError(f"mesh {path} is {path.stat().st_size / 2**30:.0f} GiB, more than probvis reads (at most "
                           f"{MAX_MESH_BYTES >> 30} GiB)")
    obj = fmt == "obj"
    try:
        read = read_obj(path.read_bytes()) if obj else read_ply(path)
    except OSError as exc:
        raise ProbvisError(f"cannot read mesh {path}: {exc.strerror or exc}") from None
    v, f, n, uv = read if read is not None else _read_general(path, fmt)
    if len(f) == 0:
        raise ProbvisError(f"mesh {path} contains no triangles")
    v = np.asarray(v, dtype=np.float64)
    f = np.asarray(f, dtype=np.int64)
    n = None if n is None or np.shape(n) != v.shape else np.asarray(n, dtype=np.float64)  # else from the faces
    uv = np.asarray(uv, dtype=np.float64).copy() if uv is not None and len(uv) == len(v) else None
    bad = vertex_problem(v, n, uv)
    if bad:
        what, statement, row = bad
        raise ProbvisError(f"{_bad_row(path, obj, statement, row, read is not None)}: mesh {path.name} has {what}")
    if uv is not None and (obj if flip_tex_coords is None else flip_tex_coords):
        uv[:, 1] = 1.0 - uv[:, 1]
    return MeshData(v, f, n, uv)


def vertex_problem(v, n, uv):
    """The first problem of a mesh's vertex attributes, as (what, the OBJ statement, vertex), or None: positions
    and normals finite, normals nonzero, texture coordinates finite and within ±MAX_UV (as a `Scene` must hold)."""
    for what, values, statement, good in (
            ("NaN or infinite vertex coordinates", v, b"v", lambda: np.isfinite(v).all(axis=1)),
            ("NaN, infinite or zero vertex normals", n, b"vn",
             lambda: np.isfinite(n).all(axis=1) & (np.einsum("ij,ij->i", n, n) > 0.0)),
            (f"NaN, infinite or huge texture coordinates (beyond ±{MAX_UV:g})", uv, b"vt",
             lambda: (np.abs(uv) <= MAX_UV).all(axis=1))):
        if values is not None and not (ok := good()).all():
            return what, statement, int(np.argmin(ok))
    return None


def _bad_row(path, obj, statement, index, in_file_order):
    """Where a mesh's bad vertex row is: file:line of an OBJ's first `statement` (v, vn, vt) whose numbers are not
    all finite and non-zero, of an ASCII PLY's row `index` of its first element; else the file and the row."""
    if obj:
        data = path.read_bytes()
        for m in re.finditer(rb"(?m)^[ \t]*" + statement + rb"[ \t]+([^\r\n]*)", data):
            try:
                row = np.array([float(x) for x in m.group(1).split()[:3]])
            except ValueError:
                continue
            if not (np.isfinite(row).all() and (statement != b"vn" or np.any(row != 0.0))
                    and (statement != b"vt" or np.all(np.abs(row) <= MAX_UV))):
                line = data.count(b"\n", 0, m.start()) + 1
                return f"{path}:{line}"
        return f"{path} (vertex {index})"
    with open(path, "rb") as fh:
        head = [fh.readline(1024) for _ in range(1000)]
    ends = [k for k, line in enumerate(head) if line.strip() == b"end_header"]
    elements = [line.split()[1:2] for line in head if line.startswith(b"element ")]
    if in_file_order and ends and b"format ascii" in b"".join(head) and elements[:1] == [[b"vertex"]]:
        return f"{path}:{ends[0] + 2 + index}"
    return f"{path} (vertex {index})"


def _read_general(path, fmt):
    """(vertices, faces, normals, uv) by trimesh's reader, with its failures and misreadings named (file:line
    for an OBJ)."""
    import trimesh

    ply = _ply_elements(path) if fmt == "ply" else {}
    if fmt == "obj" and (problem := _obj_problem(path)):
        raise ProbvisError(problem)
    try:
        with np.errstate(all="ignore"):  # trimesh's casts of NaN values warn; the values are checked below, by name
            mesh, n = _read(path, fmt)
    except Exception:  # trimesh raises many types (and leaks its own dependencies' errors) for malformed files
        problem = _obj_problem(path) if fmt == "obj" else None
        raise ProbvisError(problem or _ply_truncated(path, ply, None) or
                           f"cannot read mesh {path}: not a valid {fmt.upper()} file") from None
    if ply and (problem := _ply_truncated(path, ply, mesh)):
        raise ProbvisError(problem)
    if fmt == "obj" and (problem := _obj_checked(path, mesh)):
        raise ProbvisError(problem)
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ProbvisError(f"mesh {path} contains no triangles")
    return mesh.vertices, mesh.faces, n, getattr(mesh.visual, "uv", None)


DISK_SEGMENTS = 256  # a tessellated disk's area is (n / 2 pi) sin(2 pi / n) of the disk's: 0.99990 at 256


def disk(segments=DISK_SEGMENTS):
    """Mitsuba's disk: the unit disk in the z = 0 plane, front side +z, as a fan of `segments` triangles."""
    phi = 2.0 * np.pi * np.arange(segments) / segments
    v = np.vstack([[0.0, 0.0, 0.0], np.column_stack([np.cos(phi), np.sin(phi), np.zeros(segments)])])
    j = np.arange(segments)
    f = np.column_stack([np.zeros(segments, np.int64), 1 + j, 1 + (j + 1) % segments])
    return v, f


def cylinder(segments=DISK_SEGMENTS, rings=1):
    """Mitsuba's cylinder: radius 1 around the z axis from z = 0 to z = 1, open, outward-facing, with its exact
    (radial) vertex normals."""
    phi = 2.0 * np.pi * np.arange(segments) / segments
    z = np.linspace(0.0, 1.0, rings + 1)
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    v = np.stack([np.cos(pp), np.sin(pp), zz], axis=-1).reshape(-1, 3)
    n = np.stack([np.cos(pp), np.sin(pp), np.zeros_like(pp)], axis=-1).reshape(-1, 3)
    faces = []
    for i in range(rings):
        for j in range(segments):
            a, b = i * segments + j, i * segments + (j + 1) % segments
            c, d = a + segments, b + segments
            faces += [[a, b, d], [a, d, c]]
    return v, np.array(faces, dtype=np.int64), n
