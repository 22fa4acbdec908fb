"""The binary PLY reader (`scene.ply.read_ply`) against trimesh's reader, and the files it leaves to it."""
import re

import numpy as np
import pytest

from probvis.scene import shapes
from probvis.scene.ply import read_ply

RNG = np.random.default_rng(3)
V = RNG.normal(size=(40, 3))
N = V / np.linalg.norm(V, axis=1, keepdims=True)
UV = RNG.uniform(size=(40, 2))
F = RNG.integers(0, 40, size=(60, 3))


def write_ply(path, order="<", normals=True, uv=("u", "v"), faces=F, fmt=None, truncate=0, index="vertex_indices",
              uv_values=UV):
    """A binary PLY of V (float32) and `faces` (uchar counts, int32 indices) in byte order `order`."""
    props = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals else []) + (list(uv) if uv else [])
    cols = [V] + ([N] if normals else []) + ([uv_values] if uv else [])
    fmt = fmt or ("binary_little_endian" if order == "<" else "binary_big_endian")
    head = (f"ply\nformat {fmt} 1.0\ncomment made by a test\nelement vertex {len(V)}\n"
            + "".join(f"property float {p}\n" for p in props)
            + f"element face {len(faces)}\nproperty list uchar int {index}\nend_header\n").encode()
    verts = np.hstack(cols).astype(order + "f4").tobytes()
    rows = b"".join(np.array([len(f)], "u1").tobytes() + np.asarray(f, order + "i4").tobytes() for f in faces)
    data = head + verts + rows
    path.write_bytes(data[:len(data) - truncate])
    return path


@pytest.mark.parametrize("order", ["<", ">"])
@pytest.mark.parametrize("normals, uv", [(True, ("u", "v")), (False, ("s", "t")), (True, None)])
def test_binary_triangles_read_as_trimesh_reads_them(tmp_path, order, normals, uv):
    path = write_ply(tmp_path / "m.ply", order, normals, uv)
    v, f, n, t = read_ply(path)
    v2, f2, n2, t2 = shapes._read_general(path, "ply")
    np.testing.assert_array_equal(v, np.asarray(v2))
    np.testing.assert_array_equal(f, np.asarray(f2))
    np.testing.assert_array_equal(f, F)
    np.testing.assert_array_equal(v, V.astype(np.float32))
    if normals:
        np.testing.assert_array_equal(n, np.asarray(n2))
    else:
        assert n is None
    if uv:
        np.testing.assert_array_equal(t, UV.astype(np.float32))
        np.testing.assert_array_equal(t, np.asarray(t2))
    else:
        assert t is None
    mesh = shapes.load_mesh(path)
    np.testing.assert_array_equal(mesh.faces, F)


def test_polygons_are_split_into_fans(tmp_path):
    """(trimesh's reader refuses a binary PLY with a quad among triangles.)"""
    faces = [[0, 1, 2, 3, 4]] + list(F[1:])
    v, f, _, _ = read_ply(write_ply(tmp_path / "m.ply", faces=faces))
    np.testing.assert_array_equal(f, np.vstack([[[0, 1, 2], [0, 2, 3], [0, 3, 4]], F[1:]]))


@pytest.mark.parametrize("kind", ["ascii", "truncated"])
def test_files_it_cannot_map_go_to_the_general_reader(tmp_path, kind):
    path = write_ply(tmp_path / "m.ply", faces=F, truncate=5 if kind == "truncated" else 0,
                     fmt="ascii" if kind == "ascii" else None)
    assert read_ply(path) is None


def test_a_binary_ply_s_index_out_of_range_is_named(tmp_path):
    from probvis.errors import ProbvisError

    path = write_ply(tmp_path / "m.ply", faces=np.vstack([F, [[0, 1, 40]]]))
    with pytest.raises(ProbvisError, match="m.ply: a face has vertex index 40; its 40 vertices are numbered from 0 "
                       "to 39"):
        shapes.load_mesh(path)


def test_a_negative_element_count_is_named(tmp_path):
    from probvis.errors import ProbvisError

    path = write_ply(tmp_path / "m.ply")
    path.write_bytes(path.read_bytes().replace(b"element vertex 40", b"element vertex -4", 1))
    with pytest.raises(ProbvisError, match="malformed PLY header: element .vertex. count .-4. is not a whole number"):
        shapes.load_mesh(path)


def test_non_finite_texture_coordinates_are_named(tmp_path):
    from probvis.errors import ProbvisError

    bad = UV.copy()
    bad[3, 0] = np.nan
    path = write_ply(tmp_path / "m.ply", uv_values=bad)
    with pytest.raises(ProbvisError, match="has NaN, infinite or huge texture coordinates"):
        shapes.load_mesh(path)


def test_a_nan_in_an_ascii_ply_is_named_without_a_warning(tmp_path):
    """trimesh reads ASCII PLY; its casts of a NaN warn: the one line is the named error."""
    import warnings

    from probvis.errors import ProbvisError

    path = tmp_path / "m.ply"
    path.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                    "property float u\nproperty float v\nelement face 1\nproperty list uchar int vertex_indices\n"
                    "end_header\n0 0 0 nan 0\n1 0 0 1 0\n0 1 0 0 1\n3 0 1 2\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ProbvisError, match="m.ply:12: mesh m.ply has NaN, infinite or huge texture coordinates"):
            shapes.load_mesh(path)


def test_other_face_lists_are_ignored_and_unknown_formats_refused(tmp_path):
    """A per-face texcoord list beside the indices was refused as truncated; binary_middle_endian was read."""
    from probvis.errors import ProbvisError

    head = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 1\nproperty list uchar int vertex_indices\nproperty list uchar float texcoord\nend_header\n")
    path = tmp_path / "lists.ply"
    path.write_text(head + "0 0 0\n1 0 0\n0 1 0\n3 0 1 2 6 0 0 1 0 0 1\n")
    np.testing.assert_array_equal(shapes.load_mesh(path).faces, [[0, 1, 2]])
    path.write_text(head.replace("ascii", "binary_middle_endian") + "0 0 0\n1 0 0\n0 1 0\n3 0 1 2 6 0 0 1 0 0 1\n")
    with pytest.raises(ProbvisError, match="PLY format 'binary_middle_endian' is not one of ascii, binary_little"):
        shapes.load_mesh(path)


@pytest.mark.parametrize("face, problem", [("4 0 1 2", "early end-of-line"), ("3 0 1 2.5", "malformed input")])
def test_an_ascii_ply_whose_rows_do_not_match_its_header_is_named(tmp_path, face, problem):
    """trimesh read a short face list and a fractional index (truncated to 2) without a word."""
    from probvis.errors import ProbvisError

    path = tmp_path / "m.ply"
    path.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                    "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n"
                    f"{face}\n")
    with pytest.raises(ProbvisError, match=f"m.ply: malformed ASCII PLY: element 'face': row 0: .*{problem}"):
        shapes.load_mesh(path)


def test_an_ascii_ply_with_another_element_is_read():
    """Mitsuba skips elements it does not use (an edge list): probvis called the file truncated."""
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "m.ply"
        path.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                        "property float z\nelement face 1\nproperty list uchar int vertex_indices\nelement edge 1\n"
                        "property int vertex1\nproperty int vertex2\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n0 1\n")
        mesh = shapes.load_mesh(path)
    assert mesh[1].tolist() == [[0, 1, 2]] and mesh[0].shape == (3, 3)


@pytest.mark.parametrize("edit, message", [
    (("property float x", "property half x"), "malformed PLY header: line 4: field type 'half' is not one of PLY's"),
    (("element face 1", "element face 2.5"), "malformed PLY header: element 'face' count '2.5' is not a whole number"),
    (("format ascii 1.0\n", ""), "malformed PLY header: no 'format' line"),
    (("format ascii 1.0", "format ascii 1.0 extra"), "the format line 'format ascii 1.0 extra' is not 'format <"),
    (("format ascii 1.0", "format ascii 2.0"), "malformed PLY header: PLY version '2.0' is not 1.0, the only one"),
    (("format ascii 1.0", "format ascii 1.0\nformat ascii 1.0"), "malformed PLY header: line 3: a second 'format' line"),
    (("3 0 1 2\n", "3 0 1 2\n\n3 2 1 0\n"), "m.ply:15: data after the 4 rows the header declares (vertex 3, face 1): "
                                         "correct the header's counts"),
])
def test_a_malformed_header_is_named(tmp_path, edit, message):
    """A property type PLY does not have; an element count that is no whole number (reported as '0 faces'); a
    version other than 1.0, a second format line and rows beyond the header's counts, which Mitsuba refuses
    (probvis read them)."""
    from probvis.errors import ProbvisError

    path = tmp_path / "m.ply"
    path.write_text(("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                     "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n"
                     "3 0 1 2\n").replace(*edit))
    with pytest.raises(ProbvisError, match=re.escape(message)):
        shapes.load_mesh(path)


@pytest.mark.parametrize("extra", [b"", b"\x00" * 70])
def test_bytes_after_a_binary_ply_s_data_are_refused(tmp_path, extra):
    """Sweep 49: a binary PLY with bytes after its declared rows (a damaged or joined file) loaded as the valid
    one, where Mitsuba refuses it ("trailing content"); the ASCII form was refused already."""
    from probvis.errors import ProbvisError

    path = tmp_path / "m.ply"
    path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                     b"property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
                     + np.array([0, 0, 0, 1, 0, 0, 0, 1, 0], "<f4").tobytes() + b"\x03"
                     + np.array([0, 1, 2], "<i4").tobytes() + extra)
    if not extra:
        assert shapes.load_mesh(path)[1].tolist() == [[0, 1, 2]]
        return
    with pytest.raises(ProbvisError, match=re.escape("m.ply: 70 bytes after the data its header declares (vertex 3, "
                                                     "face 1): a damaged or joined file (Mitsuba refuses")):
        shapes.load_mesh(path)


@pytest.mark.parametrize("edit", [("\n", "\r\n"), ("3 0 1 2\n", "3 0 1 2\n\n  \n"), ("3 0 1 2\n", "3 0 1 2")])
def test_line_endings_and_blank_lines_after_the_rows_still_load(tmp_path, edit):
    """The trailing-rows check counts rows, not lines: Windows line endings, blank lines at the end and a last
    row without a newline load as before."""
    path = tmp_path / "m.ply"
    path.write_bytes(("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                      "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n"
                      "3 0 1 2\n").replace(*edit).encode())
    assert shapes.load_mesh(path)[1].tolist() == [[0, 1, 2]]


@pytest.mark.parametrize("faces, header_vertices, message", [
    ("0\n3 0 1 2\n", 3, "face 0 has 0 vertices; a face needs at least 3"),
    ("3 0 1 2\n2 0 1\n", 3, "face 1 has 2 vertices; a face needs at least 3"),
    ("3 0 1 2\n", 10 ** 9, "its header declares 1,000,000,000 vertices and 2 faces, at least 6,000,000,004 bytes, "
                          "more than its"),
])
def test_short_faces_and_counts_the_file_cannot_hold_are_named(tmp_path, faces, header_vertices, message):
    """A face of fewer than 3 vertices (a vague 'truncated' and NumPy's loadtxt warning before); an ASCII header
    declaring more rows than the file's bytes can hold, refused before anything is allocated (out of memory)."""
    import warnings

    from probvis.errors import ProbvisError

    path = tmp_path / "m.ply"
    path.write_text(f"ply\nformat ascii 1.0\nelement vertex {header_vertices}\nproperty float x\nproperty float y\n"
                    "property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n"
                    "0 0 0\n1 0 0\n0 1 0\n" + faces)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ProbvisError, match=re.escape(message)):
            shapes.load_mesh(path)


@pytest.mark.parametrize("faces", [50_000_000, 4_000_000_000])
def test_a_binary_face_count_the_file_cannot_hold_is_refused_before_reading(tmp_path, faces):
    """A 226-byte binary PLY declaring 400M faces took 17 s and 3.3 GB before 'truncated' (4e9: a false 'out of
    memory'): only ASCII files had their counts checked against their size."""
    from probvis.errors import ProbvisError

    path = tmp_path / "m.ply"
    path.write_bytes(f"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                     f"property float z\nelement face {faces}\nproperty list uchar int vertex_indices\nend_header\n"
                     .encode() + np.array([0, 0, 0, 1, 0, 0, 0, 1, 0], "<f4").tobytes() + bytes([3])
                     + np.arange(3, dtype="<i4").tobytes())
    with pytest.raises(ProbvisError, match=re.escape(f"declares 3 vertices and {faces:,} faces, at least "
                                                     f"{faces + 36:,} bytes, more than its")):
        shapes.load_mesh(path)


@pytest.mark.parametrize("order", ["<", ">"])
@pytest.mark.parametrize("sizes, message", [((0, 3), "face 0 has 0 vertices"), ((3, 2), "face 1 has 2 vertices"),
                                            ((3, 1), "face 1 has 1 vertices")])
def test_short_faces_of_a_binary_ply_are_named(tmp_path, order, sizes, message):
    """The binary reader's fixed face length broke on a short face, which then read as 'truncated or malformed'."""
    from probvis.errors import ProbvisError

    fmt = "binary_little_endian" if order == "<" else "binary_big_endian"
    body = np.array([0, 0, 0, 1, 0, 0, 0, 1, 0], f"{order}f4").tobytes()
    for n in sizes:
        body += bytes([n]) + np.arange(n, dtype=f"{order}i4").tobytes()
    path = tmp_path / "m.ply"
    path.write_bytes(f"ply\nformat {fmt} 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                     f"element face 2\nproperty list uchar int vertex_indices\nend_header\n".encode() + body)
    with pytest.raises(ProbvisError, match=re.escape(f"{message}; a face needs at least 3")):
        shapes.load_mesh(path)


@pytest.mark.parametrize("faces, message", [
    ("element face 0\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n", "contains no triangles"),
    ("element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n",
     "a face has vertex index -1; its 3 vertices are numbered from 0 to 2"),
    ("element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n",
     "a face has vertex index 3; its 3 vertices are numbered from 0 to 2"),
])
def test_an_ascii_ply_without_faces_or_with_indices_out_of_range_says_so(tmp_path, faces, message):
    """`element face 0` was said to hold indices of the wrong type; an index out of range was not named, nor its
    file."""
    from probvis.errors import ProbvisError

    path = tmp_path / "m.ply"
    path.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                    + faces)
    with pytest.raises(ProbvisError, match=f"mesh .*m.ply:? {message}" if "no" in message else f"m.ply: {message}"):
        shapes.load_mesh(path)


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian"])
def test_a_face_element_without_an_index_list_is_named(tmp_path, fmt):
    """It was said to be "truncated or malformed"; Mitsuba says the vertex_indices property is missing."""
    from probvis.errors import ProbvisError

    path = tmp_path / "m.ply"
    head = (f"ply\nformat {fmt} 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 1\nproperty int a\nproperty int b\nproperty int c\nend_header\n")
    body = ("0 0 0\n1 0 0\n0 1 0\n0 1 2\n".encode() if fmt == "ascii" else
            np.array([0, 0, 0, 1, 0, 0, 0, 1, 0], "<f4").tobytes() + np.array([0, 1, 2], "<i4").tobytes())
    path.write_bytes(head.encode() + body)
    with pytest.raises(ProbvisError, match="m.ply: its face element has no vertex_indices \\(or vertex_index\\) list"):
        shapes.load_mesh(path)
