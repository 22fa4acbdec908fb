"""Wavefront OBJ files read as Mitsuba reads them, with numpy over the whole file.

One mesh in file order (grouping and material statements ignored), polygons split into fans around their first
corner, and where faces name texture coordinates or normals a vertex per distinct (position, uv, normal) index
triple, numbered in order of first use. The statements are told apart by their lines' first bytes (by regular
expressions where a statement is indented or carries a comment) and their numbers parsed in one call each;
faces whose corners are not all of one form, or that count back (negative indices), are read statement by
statement. A file it cannot read returns None: the caller names the line.
"""
import re

import numpy as np

_KINDS = (b"v", b"vt", b"vn", b"f")  # the statements read
_BARE = re.compile(rb"(?m)^[ \t]*(?:v|vt|vn|f)[ \t]*(?:#[^\r\n]*)?\r?$")  # a statement without numbers: named
_STATEMENT = {kind: re.compile(rb"(?m)^[ \t]*" + kind + rb"[ \t]+([^\r\n#]*)") for kind in _KINDS}
_WHITESPACE = np.zeros(256, bool)
_WHITESPACE[[9, 10, 13, 32]] = True
_BLANK = np.zeros(256, bool)  # the separator after a statement's keyword
_BLANK[[9, 32]] = True


def _statements(data):
    """Per kind (v, vt, vn, f) the bodies of its statements in file order, as `_STATEMENT` finds them, and
    whether a statement has no numbers (`_BARE`). Where no line is indented and no statement carries a comment
    or a lone carriage return, a line's kind is read off its first three bytes, for all lines at once (a large
    mesh's four expressions took 60 ms, the bare-statement search 23 ms); otherwise the expressions run."""
    data = data.replace(b"\r\n", b"\n")
    text = np.frombuffer(data, np.uint8)
    ends = np.flatnonzero(text == 10)
    starts = np.concatenate([[0], ends + 1])
    head = np.concatenate([text, np.zeros(3, np.uint8)])  # a line's first three bytes, past its end if short
    b0, b1, b2 = head[starts], head[starts + 1], head[starts + 2]
    kind = np.full(len(starts), -1, np.int8)
    kind[(b0 == ord("v")) & _BLANK[b1]] = 0
    kind[(b0 == ord("v")) & (b1 == ord("t")) & _BLANK[b2]] = 1
    kind[(b0 == ord("v")) & (b1 == ord("n")) & _BLANK[b2]] = 2
    kind[(b0 == ord("f")) & _BLANK[b1]] = 3
    commented = kind[np.searchsorted(ends, np.flatnonzero(text == ord("#")))] >= 0
    if _BLANK[b0].any() or commented.any() or b"\r" in data:
        bodies = {name.decode(): _STATEMENT[name].findall(data) for name in _KINDS}
        return bodies, _BARE.search(data) is not None
    lines = data.split(b"\n")
    others = np.flatnonzero((kind < 0) & ((b0 == ord("v")) | (b0 == ord("f"))))  # a bare `v` or `f`, or `vp`
    bare = any(_BARE.match(lines[i]) for i in others)
    bodies = {}
    for k, name in enumerate(_KINDS):
        skip = len(name) + 1
        bodies[name.decode()] = [lines[i][skip:] for i in np.flatnonzero(kind == k).tolist()]
    return bodies, bare


def _tokens_per_line(bodies):
    """How many whitespace-separated tokens each of the statement bodies holds."""
    text = np.frombuffer(b"\n".join(bodies) + b"\n", np.uint8)
    space = _WHITESPACE[text]
    starts = np.flatnonzero(~space & np.concatenate([[True], space[:-1]]))
    ends = np.flatnonzero(text == 10)
    return np.bincount(np.searchsorted(ends, starts), minlength=len(bodies))


def _numbers(bodies, dtype, width, minimum=None):
    """The statements' numbers as an (n, width) array of their first `width` values, missing ones zero where a
    statement has at least `minimum` (None if one has fewer, or a token is not a number; a `w` or colour after
    them is ignored, as Mitsuba does)."""
    if not bodies:
        return np.zeros((0, width), dtype)
    counts = _tokens_per_line(bodies)
    if counts.min() < (minimum or width):
        return None
    if counts.min() < width:  # pad the short statements, then read as usual
        bodies = [b + b" 0" * (width - c) if c < width else b for b, c in zip(bodies, counts)]
        counts = np.maximum(counts, width)
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


def _uniform_corners(faces):
    """Per corner its (v, vt, vn) indices as written (-1 where the form has none) and per face its corner count,
    where every face has at least three corners of one form; None otherwise."""
    first = faces[0].split(None, 1)[0] if faces[0].strip() else b""
    slashes, doubled = first.count(b"/"), b"//" in first
    if slashes > 2 or first.startswith(b"/"):
        return None
    counts = _tokens_per_line(faces)
    joined = b" ".join(faces)
    n_corners = int(counts.sum())
    if counts.min() < 3 or joined.count(b"/") != slashes * n_corners or joined.count(b"//") != doubled * n_corners:
        return None
    columns = [0] + ([1] if slashes and not doubled else []) + ([2] if slashes == 2 else [])
    try:
        idx = np.fromstring(joined.replace(b"/", b" "), dtype=np.int64, sep=" ")
    except ValueError:
        return None
    if len(idx) != len(columns) * n_corners or not idx.all():  # an index 0 is invalid (they start at 1)
        return None
    out = np.zeros((n_corners, 3), np.int64)  # 0: none (OBJ indices start at 1)
    out[:, columns] = idx.reshape(n_corners, len(columns))
    return out, counts


def _corners_by_line(data):
    """`_uniform_corners` of any layout, statement by statement: corners of different forms, and relative
    (negative) indices counted back from the statements before the face. None if a face cannot be read."""
    defined = {b"v": 0, b"vt": 0, b"vn": 0}
    corners, counts = [], []
    for line in data.split(b"\n"):
        words = line.split(b"#", 1)[0].split()
        if not words:
            continue
        if words[0] in defined:
            defined[words[0]] += 1
        elif words[0] == b"f":
            if len(words) < 4:
                return None
            for word in words[1:]:
                parts = word.split(b"/")
                if len(parts) > 3 or not parts[0]:
                    return None
                row = []
                for kind, text in zip((b"v", b"vt", b"vn"), parts + [b""] * (3 - len(parts))):
                    try:
                        k = int(text) if text else 0
                    except ValueError:
                        return None
                    if text and k == 0:
                        return None
                    row.append(k if k >= 0 else defined[kind] + k + 1 if defined[kind] + k >= 0 else -1)
                corners.append(row)
            counts.append(len(words) - 1)
    if not counts:
        return None
    return np.array(corners, np.int64), np.array(counts, np.int64)


def read_obj(data):
    """(vertices, faces, normals or None, uv or None) of an OBJ file's bytes, uv as stored (not flipped); None
    where the file has a statement or face this reader cannot read (the caller names its line). A texture
    coordinate without v has v = 0; corners without uv get (0, 0); normals are kept only where every corner
    has one (else computed from the faces)."""
    data = data.removeprefix(b"\xef\xbb\xbf")  # a byte-order mark (Windows editors) would hide the first line
    bodies, bare = _statements(data)
    v = _numbers(bodies["v"], np.float64, 3)
    vt = _numbers(bodies["vt"], np.float64, 2, minimum=1)
    vn = _numbers(bodies["vn"], np.float64, 3)
    if v is None or vt is None or vn is None or not bodies["f"] or bare:
        return None
    read = _uniform_corners(bodies["f"])
    if read is None or read[0].min() < 0:
        read = _corners_by_line(data)
    if read is None:
        return None
    idx, counts = read
    idx = idx - 1  # -1: none
    for k, size in enumerate((len(v), len(vt), len(vn))):
        if idx[:, k].max() >= size or idx[:, k].min() < -1 or (k == 0 and idx[:, 0].min() < 0):
            return None
    tri = fans(counts) if counts.max() > 3 else np.arange(len(idx)).reshape(-1, 3)
    has_uv, has_normals = bool((idx[:, 1] >= 0).any()), bool((idx[:, 2] >= 0).all())
    if (not has_uv and not (idx[:, 2] >= 0).any()) or not np.isfinite(v).all():
        # positions in file order; a non-finite one, used or not, is refused at its line (as Mitsuba refuses it)
        return v, idx[:, 0][tri], None, None
    # a vertex per distinct index triple, in order of first use (as Mitsuba's reader numbers them)
    keys, first_use, corner_vertex = np.unique(idx, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first_use, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    keys = keys[order]
    uv = np.where(keys[:, 1:2] >= 0, vt[keys[:, 1]], 0.0) if has_uv else None
    normals = vn[keys[:, 2]] if has_normals else None
    return v[keys[:, 0]], rank[corner_vertex.reshape(-1)][tri], normals, uv
