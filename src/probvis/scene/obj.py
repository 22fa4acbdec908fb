"""Wavefront OBJ files read as Mitsuba reads them, with numpy over the whole file.

One mesh in file order (grouping and material statements ignored), polygons split into fans around their first
corner, and where faces name texture coordinates or normals a vertex per distinct (position, uv, normal) index
triple, numbered in order of first use. The statements are gathered by regular expressions and their numbers
parsed in one call each; what this layout cannot read exactly (corners of different forms, negative indices, a
statement it cannot parse) returns None, and the caller falls back to a general reader.
"""
import re

import numpy as np

_STATEMENT = {kind: re.compile(rb"(?m)^[ \t]*" + kind + rb"[ \t]+([^\r\n#]*)") for kind in (b"v", b"vt", b"vn", b"f")}
_WHITESPACE = np.zeros(256, bool)
_WHITESPACE[[9, 10, 13, 32]] = True


def _tokens_per_line(bodies):
    """How many whitespace-separated tokens each of the statement bodies holds."""
    text = np.frombuffer(b"\n".join(bodies) + b"\n", np.uint8)
    space = _WHITESPACE[text]
    starts = np.flatnonzero(~space & np.concatenate([[True], space[:-1]]))
    ends = np.flatnonzero(text == 10)
    return np.bincount(np.searchsorted(ends, starts), minlength=len(bodies))


def _numbers(bodies, dtype, width):
    """The statements' numbers as an (n, width) array of their first `width` values (None if any statement has
    fewer, or a token is not a number; a `w` or colour after them is ignored, as Mitsuba does)."""
    if not bodies:
        return np.zeros((0, width), dtype)
    counts = _tokens_per_line(bodies)
    if counts.min() < width:
        return None
    try:
        flat = np.fromstring(b" ".join(bodies), dtype=dtype, sep=" ")
    except ValueError:
        return None
    if len(flat) != counts.sum():
        return None
    if np.all(counts == width):
        return flat.reshape(-1, width)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    return flat[first[:, None] + np.arange(width)]


def fans(counts):
    """Corner indices (into the faces' corners in file order) of the fan triangles of faces of `counts` corners."""
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    n_tri = counts - 2
    face = np.repeat(np.arange(len(counts)), n_tri)
    j = np.arange(n_tri.sum()) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri)  # 0 .. n_tri - 1 within each face
    base = first[face]
    return np.column_stack([base, base + j + 1, base + j + 2])


def read_obj(data):
    """(vertices, faces, normals or None, uv or None) of an OBJ file's bytes, uv as stored (not flipped); None
    where the layout needs the general reader, or the file has a face this reader would misread (the caller
    names its line)."""
    bodies = {kind.decode(): _STATEMENT[kind].findall(data) for kind in _STATEMENT}
    v = _numbers(bodies["v"], np.float64, 3)
    vt = _numbers(bodies["vt"], np.float64, 2)
    vn = _numbers(bodies["vn"], np.float64, 3)
    faces = bodies["f"]
    if v is None or vt is None or vn is None or not faces:
        return None
    first = faces[0].split(None, 1)[0] if faces[0].strip() else b""
    slashes, doubled = first.count(b"/"), b"//" in first
    if slashes > 2 or first.startswith(b"/"):
        return None
    fields = 1 + slashes - doubled  # numbers per corner: v, v/vt, v//vn, v/vt/vn
    counts = _tokens_per_line(faces)
    joined = b" ".join(faces)
    n_corners = int(counts.sum())
    if counts.min() < 3 or joined.count(b"/") != slashes * n_corners or joined.count(b"//") != doubled * n_corners:
        return None
    try:
        idx = np.fromstring(joined.replace(b"/", b" "), dtype=np.int64, sep=" ")
    except ValueError:
        return None
    if len(idx) != fields * n_corners:
        return None
    idx = idx.reshape(n_corners, fields) - 1
    kinds = ["v"] + (["vt"] if slashes and not doubled else []) + (["vn"] if slashes == 2 else [])
    sizes = {"v": len(v), "vt": len(vt), "vn": len(vn)}
    for k, kind in enumerate(kinds):
        if idx[:, k].min() < 0 or idx[:, k].max() >= sizes[kind]:  # negative (relative) or out of range
            return None
    tri = fans(counts) if counts.max() > 3 else np.arange(n_corners).reshape(-1, 3)
    if fields == 1:
        return v, idx[:, 0][tri], None, None
    # a vertex per distinct index triple, in order of first use (as Mitsuba's reader numbers them)
    keys, first_use, corner_vertex = np.unique(idx, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first_use, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    keys = keys[order]
    faces_out = rank[corner_vertex.reshape(-1)][tri]
    uv = vt[keys[:, kinds.index("vt")]] if "vt" in kinds else None
    normals = vn[keys[:, kinds.index("vn")]] if "vn" in kinds else None
    return v[keys[:, 0]], faces_out, normals, uv
