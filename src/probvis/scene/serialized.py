"""Mitsuba's `.serialized` meshes (format versions 3 and 4): a zlib stream per mesh after a 4-byte header, an
offset table at the end of the file. Only what a mesh's header declares is decompressed."""
import struct
import zlib
from pathlib import Path

import numpy as np

from ..errors import ProbvisError
from .shapes import MAX_MESH_BYTES, MeshData, vertex_problem

SERIALIZED_MAGIC = 0x041C
MAX_INFLATE_RATIO = 1032  # zlib's largest compression ratio
_SER_NORMALS, _SER_TEXCOORDS, _SER_COLORS, _SER_DOUBLE = 0x0001, 0x0002, 0x0008, 0x2000


def _serialized_header(raw, version):
    """(flags, offset of the arrays, vertex count, face count) of a decompressed serialized mesh."""
    (flags,) = struct.unpack_from("<I", raw, 0)
    pos = raw.index(b"\0", 4) + 1 if version == 4 else 4  # version 4 names the mesh
    n_v, n_f = struct.unpack_from("<QQ", raw, pos)
    return flags, pos + 16, n_v, n_f


def _serialized_bytes(flags, n_v, n_f):
    """Bytes of a serialized mesh's arrays: positions, normals, uv and colours per vertex, indices per face."""
    real = 8 if flags & _SER_DOUBLE else 4
    per_vertex = 3 + 3 * bool(flags & _SER_NORMALS) + 2 * bool(flags & _SER_TEXCOORDS) + 3 * bool(flags & _SER_COLORS)
    return n_v * per_vertex * real + 3 * n_f * (8 if n_v > 0xFFFFFFFF else 4)


def _inflate_mesh(stream, version):
    """The decompressed bytes of one mesh of a serialized file, with its header's (flags, offset of the arrays,
    vertex count, face count): the header first, then exactly the arrays the header
    declares (never the rest of the stream: a file may hold gigabytes of anything after a valid mesh), refused
    when they could not fit in the compressed bytes or in memory."""
    inflate = zlib.decompressobj()
    raw = inflate.decompress(stream, 1 << 16)  # flags, a name of at most a few KiB, the counts
    flags, pos, n_v, n_f = _serialized_header(raw, version)
    need = pos + _serialized_bytes(flags, n_v, n_f)
    if need > MAX_INFLATE_RATIO * len(stream) + (1 << 16) or need > MAX_MESH_BYTES:
        raise ValueError(f"it declares {n_v} vertices and {n_f} triangles, {need / 2**20:.0f} MiB that its "
                         f"{len(stream)} compressed bytes cannot hold")
    if len(raw) < need:
        raw += inflate.decompress(inflate.unconsumed_tail, need - len(raw))
    if len(raw) < need:
        raise ValueError(f"it declares {n_v} vertices and {n_f} triangles, but its data ends after {len(raw)} bytes")
    return raw, flags, pos, n_v, n_f


def load_serialized(path, shape_index=0):
    """Mesh `shape_index` of a Mitsuba `.serialized` file (format versions 3 and 4: a zlib stream per mesh, an
    offset table at the end) as `MeshData`."""
    path = Path(path)
    try:
        if path.stat().st_size > MAX_MESH_BYTES:
            raise ProbvisError(f"mesh {path} is {path.stat().st_size / 2**30:.0f} GiB, more than probvis reads (at "
                               f"most {MAX_MESH_BYTES >> 30} GiB)")
        data = path.read_bytes()
    except OSError as exc:
        raise ProbvisError(f"cannot read mesh {path}: {exc.strerror or exc}") from None
    if len(data) < 8:
        raise ProbvisError(f"{path} is not a Mitsuba serialized mesh (too short)")
    magic, version = struct.unpack_from("<HH", data, 0)
    if magic != SERIALIZED_MAGIC:
        raise ProbvisError(f"{path} is not a Mitsuba serialized mesh (format id {magic:#06x})")
    if version not in (3, 4):
        raise ProbvisError(f"{path}: serialized format version {version} is not supported (3 and 4 are)")
    (count,) = struct.unpack_from("<I", data, len(data) - 4)
    size = 8 if version == 4 else 4
    if count * size + 4 > len(data):
        raise ProbvisError(f"{path}: corrupt serialized file (its table lists {count} meshes, more than its "
                           f"{len(data)} bytes hold)")
    if not 0 <= shape_index < max(count, 1):
        raise ProbvisError(f"{path}: shape_index {shape_index} is out of range (the file holds {count} meshes)")
    offset = 0
    if shape_index > 0:
        (offset,) = struct.unpack_from("<Q" if version == 4 else "<I", data,
                                       len(data) - 4 - size * (count - shape_index))
    if not 0 <= offset < len(data) - 4:
        raise ProbvisError(f"{path}: corrupt serialized file (mesh {shape_index} starts at byte {offset}, beyond its "
                           f"{len(data)} bytes)")
    try:
        raw, flags, pos, n_v, n_f = _inflate_mesh(data[offset + 4:], version)
    except (zlib.error, struct.error, ValueError) as exc:
        raise ProbvisError(f"{path}: corrupt serialized mesh {shape_index} ({exc})") from None
    real = np.float64 if flags & _SER_DOUBLE else np.float32

    def take(n, dtype):
        nonlocal pos
        out = np.frombuffer(raw, dtype=dtype, count=n, offset=pos)
        pos += out.nbytes
        return out

    v = take(3 * n_v, real).reshape(-1, 3).astype(np.float64)
    n = take(3 * n_v, real).reshape(-1, 3).astype(np.float64) if flags & _SER_NORMALS else None
    uv = take(2 * n_v, real).reshape(-1, 2).astype(np.float64) if flags & _SER_TEXCOORDS else None
    if flags & _SER_COLORS:
        take(3 * n_v, real)
    f = take(3 * n_f, np.uint64 if n_v > 0xFFFFFFFF else np.uint32).reshape(-1, 3).astype(np.int64)
    if len(f) == 0:
        raise ProbvisError(f"mesh {shape_index} of {path} contains no triangles")
    bad = vertex_problem(v, n, uv)
    if bad:
        raise ProbvisError(f"mesh {shape_index} of {path} has {bad[0]} (vertex {bad[2]})")
    return MeshData(v, f, n, uv)
