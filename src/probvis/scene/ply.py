"""PLY files of triangles read by `plyfile`: binary ones memory-mapped with the faces' list length known,
ASCII ones row by row, a row that does not match the header named.

A scanned mesh is almost always binary: a vertex element of scalar properties and a face element whose only list
holds three indices. Polygons are read row by row and split into fans around their first corner, as Mitsuba
does. Anything else (other list properties, a file shorter than its header says) returns None, and the caller
falls back to the general reader, which also names what is wrong.
"""
import io
import re
import warnings
from pathlib import Path

import numpy as np

from ..errors import ProbvisError
from .obj import fans

UV_NAMES = (("u", "v"), ("s", "t"), ("texture_u", "texture_v"), ("texture_s", "texture_t"))
FORMATS = ("ascii", "binary_little_endian", "binary_big_endian")
INDEX_NAMES = ("vertex_indices", "vertex_index")  # the face list that holds the corners, where there are several
HEADER_LINES = 1000  # a header longer than this is left to the general reader
TYPE_BYTES = {b"char": 1, b"int8": 1, b"uchar": 1, b"uint8": 1, b"short": 2, b"int16": 2, b"ushort": 2,
              b"uint16": 2, b"int": 4, b"int32": 4, b"uint": 4, b"uint32": 4, b"float": 4, b"float32": 4,
              b"double": 8, b"float64": 8}


def _header(fh):
    """(format, {element: [(property, is_list, least bytes in a binary row)]}, {element: count}) of a PLY header,
    or None if it is not one this reader takes (a list's least bytes are its count's: it may be empty)."""
    if fh.readline(16).strip() != b"ply":
        return None
    fmt, elements, counts, current = None, {}, {}, None
    for line in range(2, HEADER_LINES + 2):
        words = fh.readline(1024).split()
        if not words or words[0] in (b"comment", b"obj_info"):
            continue
        if words[0] == b"end_header":
            return fmt, elements, counts
        if words[0] == b"format":
            if fmt is not None:  # Mitsuba refuses it too ("duplicate format tag"): which one holds is a guess
                raise ValueError(f"line {line}: a second 'format' line: a header has one")
            if len(words) != 3:
                raise ValueError(f"the format line '{b' '.join(words).decode('ascii', 'replace')}' is not "
                                 "'format <ascii|binary_little_endian|binary_big_endian> 1.0'")
            fmt = words[1].decode("ascii", "replace")
            if words[2] != b"1.0":  # Mitsuba refuses another ("PLY file has unknown version number")
                raise ValueError(f"PLY version '{words[2].decode('ascii', 'replace')}' is not 1.0, the only one: "
                                 f"write 'format {words[1].decode('ascii', 'replace')} 1.0'")
        elif words[0] == b"element" and len(words) == 3:
            if not words[2].isdigit():
                raise ValueError(f"element '{words[1].decode('ascii', 'replace')}' count "
                                 f"'{words[2].decode('ascii', 'replace')}' is not a whole number")
            current = elements.setdefault(words[1].decode("ascii", "replace"), [])
            counts[words[1].decode("ascii", "replace")] = int(words[2])
        elif words[0] == b"property" and current is not None:
            is_list = words[1] == b"list"
            size = TYPE_BYTES.get(words[2] if is_list and len(words) > 2 else words[1], 1)
            current.append((words[-1].decode("ascii", "replace"), is_list, size))
    return None


def _refuse_trailing_rows(path, data, counts):
    """An ASCII PLY with rows beyond those its header declares (one a row) is refused, as Mitsuba does ("trailing
    tokens"): most often the header's counts are wrong, and the rest of the mesh would be dropped unsaid. Lines
    are counted first; only a file with more lines than rows is walked, to skip blank ones and name the line."""
    end = re.search(rb"^[ \t]*end_header[ \t\r]*$", data, re.M)
    if end is None:
        return
    start = end.end() + 1
    declared = sum(counts.values())
    if data.count(b"\n", start) + 1 <= declared:
        return
    rows = 0
    for line in re.finditer(rb"[^\n]*", data[start:]):
        if line.group().strip():
            rows += 1
            if rows > declared:
                number = data.count(b"\n", 0, start + line.start()) + 1
                raise ProbvisError(f"mesh {path}:{number}: data after the {declared:,} rows the header declares "
                                   f"({', '.join(f'{e} {n:,}' for e, n in counts.items())}): correct the header's "
                                   "counts or remove the rest (Mitsuba refuses such a file)")


def read_ply(path):
    """(vertices, faces, normals or None, uv or None) of a PLY of triangles or polygons, or None where the general
    reader must read it; an ASCII file whose rows do not match its header is named (trimesh read it loosely)."""
    from plyfile import PlyData, PlyElementParseError, PlyHeaderParseError

    with open(path, "rb") as fh:
        try:
            header = _header(fh)
        except ValueError as exc:
            raise ProbvisError(f"mesh {path}: malformed PLY header: {exc}") from None
    if header is None:
        return None
    if header[0] is None:
        raise ProbvisError(f"mesh {path}: malformed PLY header: no 'format' line")
    if header[0] not in FORMATS:
        raise ProbvisError(f"mesh {path}: PLY format '{header[0]}' is not one of {', '.join(FORMATS)}")
    elements, counts = header[1], header[2]
    # refuse a count the file cannot hold before it is allocated: an ASCII row holds at least a digit and a
    # separator per property, a binary row each scalar's bytes and each list's count
    if header[0] == "ascii":
        least = sum(2 * max(len(elements[e]), 1) * n for e, n in counts.items())
    else:
        least = sum(max(sum(size for _, _, size in elements[e]), 1) * n for e, n in counts.items())
    size = Path(path).stat().st_size
    if least > size:
        raise ProbvisError(f"mesh {path}: truncated or malformed PLY (its header declares "
                           f"{counts.get('vertex', 0):,} vertices and {counts.get('face', 0):,} faces, at least "
                           f"{least:,} bytes, more than its {size:,} bytes)")
    data = Path(path).read_bytes() if header[0] == "ascii" else None
    if data is not None:
        _refuse_trailing_rows(path, data, counts)
    vertex, face = elements.get("vertex", []), elements.get("face", [])
    missing = [c for c in "xyz" if c not in {name for name, _, _ in vertex}]
    if "vertex" in elements and missing:
        raise ProbvisError(f"mesh {path}: its vertex element has no {' or '.join(repr(c) for c in missing)} "
                           "property (a PLY mesh's vertices need x, y and z)")
    lists = [name for name, is_list, _ in face if is_list]
    if "face" in elements and not lists:  # was "truncated or malformed" from the general reader
        raise ProbvisError(f"mesh {path}: its face element has no vertex_indices (or vertex_index) list property")
    index = next((name for name in INDEX_NAMES if name in lists), lists[0] if len(lists) == 1 else None)
    if index is None or any(is_list for _, is_list, _ in vertex):
        return None
    try:
        # plyfile reads ASCII through a text wrapper it leaves open: over bytes in memory nothing is left open
        # an ASCII float beyond float32 becomes inf with NumPy's warning; the non-finite vertex is named later
        with (io.BytesIO(data) if header[0] == "ascii" else open(path, "rb")) as fh, \
                np.errstate(over="ignore", invalid="ignore"), warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="loadtxt: input contained no data")  # an empty face, named below
            try:  # the faces' other lists (per-face texture coordinates, say) have no known length
                ply = PlyData.read(fh, known_list_len={"face": {index: 3}} if len(lists) == 1 else {})
            except OverflowError as exc:  # an ASCII value beyond its property's type (300 for a uchar)
                raise ProbvisError(f"mesh {path}: malformed ASCII PLY: a value does not fit its property's declared "
                                   f"type ({exc})") from None
            except PlyElementParseError as exc:
                # a face that is not a triangle (a polygon, or one of fewer than 3 vertices, named below) breaks
                # the fixed length: read again, each row as long as it says (a truncated file fails again)
                if (header[0] == "ascii" and "unexpected list length" not in str(exc)
                        and "end-of-file" not in str(exc)):
                    raise ProbvisError(f"mesh {path}: malformed ASCII PLY: {exc}") from None
                fh.seek(0)
                ply = PlyData.read(fh)
            if header[0] != "ascii" and (extra := size - fh.tell()) > 0:  # ASCII: `_refuse_trailing_rows`
                raise ProbvisError(f"mesh {path}: {extra:,} bytes after the data its header declares "
                                   f"({', '.join(f'{e} {n:,}' for e, n in counts.items())}): a damaged or joined "
                                   "file (Mitsuba refuses such a file)")
            rows = ply["face"].data[index]
            if len(rows) == 0:  # an empty object array: its dtype says nothing of the declared index type
                raise ProbvisError(f"mesh {path} contains no triangles")
            values = rows[0] if rows.dtype == object else rows
            if np.asarray(values).dtype.kind not in "iu":
                raise ProbvisError(f"mesh {path}: the faces' '{index}' are {np.asarray(values).dtype} numbers; "
                                   "vertex indices are integers (a PLY list of int, uint, ...)")
            if rows.dtype == object:  # polygons, or any ASCII file: a row per face, split into fans here
                sizes = np.array([len(r) for r in rows], dtype=np.int64)
                if sizes.min() < 3:
                    k = int(np.argmin(sizes))
                    raise ProbvisError(f"mesh {path}: face {k} has {sizes[k]} vertices; a face needs at least 3")
                f = np.concatenate(rows).astype(np.int64)[fans(sizes)]
            else:
                f = np.asarray(rows, dtype=np.int64)
            vert = ply["vertex"].data
            names = set(vert.dtype.names)
            if not {"x", "y", "z"} <= names:
                return None
            v = np.column_stack([vert["x"], vert["y"], vert["z"]]).astype(np.float64)
            n = (np.column_stack([vert["nx"], vert["ny"], vert["nz"]]).astype(np.float64)
                 if {"nx", "ny", "nz"} <= names else None)
            uv = next((np.column_stack([vert[a], vert[b]]).astype(np.float64) for a, b in UV_NAMES
                       if {a, b} <= names), None)
    except PlyHeaderParseError as exc:
        if " not in " not in str(exc):
            return None
        raise ProbvisError(f"mesh {path}: malformed PLY header: {str(exc).split(' not in ')[0]} is not one of PLY's "
                           "types (char, uchar, short, ushort, int, uint, float, double)") from None
    except (PlyElementParseError, KeyError, ValueError):
        return None
    if len(f) and (f.min() < 0 or f.max() >= len(v)):
        bad = int(f.min() if f.min() < 0 else f.max())
        raise ProbvisError(f"mesh {path}: a face has vertex index {bad:,}; its {len(v):,} vertices are numbered from 0"
                           f"{f' to {len(v) - 1:,}' if len(v) else ''}")
    return v, f, n, uv
