"""The OBJ reader (`scene.obj.read_obj`) against trimesh's reader, corner by corner, on every face form; a
vertex per distinct index triple at uv seams, as Mitsuba's reader; the layouts it leaves to the general reader."""
import subprocess
import sys

import numpy as np
import pytest

from probvis.scene import shapes
from probvis.scene.obj import read_obj

GRID = "".join(f"v {x} {y} {0.1 * x * y}\n" for y in range(3) for x in range(3))
UV = "".join(f"vt {x / 2} {y / 2}\n" for y in range(3) for x in range(3))
NORMALS = "".join(f"vn {0.1 * x} {0.1 * y} 1\n" for y in range(3) for x in range(3))


def quad_faces(form, quads):
    """The grid's four cells as faces in the given corner form (`{v}` etc.), as quads or two triangles."""
    out = []
    for y in range(2):
        for x in range(2):
            a, b, c, d = (1 + x + 3 * y, 2 + x + 3 * y, 5 + x + 3 * y, 4 + x + 3 * y)
            polys = [(a, b, c, d)] if quads else [(a, b, c), (a, c, d)]
            for p in polys:
                out.append("f " + " ".join(form.format(v=i) for i in p) + "\n")
    return "".join(out)


def corners(v, f, *attributes):
    """Per triangle its corners' positions (and attributes), each triangle rotated to start at its
    lexicographically smallest position (winding kept): readers may split a quad at another corner."""
    pos = np.asarray(v)[np.asarray(f)]
    key = pos[..., 0] * 1e6 + pos[..., 1] * 1e3 + pos[..., 2]
    roll = (np.arange(3) + np.argmin(key, axis=1)[:, None]) % 3
    rows = np.arange(len(f))[:, None]
    return [pos[rows, roll]] + [np.asarray(a)[np.asarray(f)][rows, roll] for a in attributes]


@pytest.mark.parametrize("quads", [False, True])
@pytest.mark.parametrize("form, extra", [("{v}", ""), ("{v}/{v}", UV), ("{v}//{v}", NORMALS),
                                         ("{v}/{v}/{v}", UV + NORMALS)])
def test_every_face_form_reads_as_trimesh_reads_it(tmp_path, form, extra, quads):
    """Positions, uv and normals of every triangle corner equal the general reader's; comments, grouping
    statements change nothing; quads split into fans around their first corner."""
    text = ("# a grid\no grid\n" + GRID + extra + "usemtl a\ng part\n"
            + quad_faces(form, quads) + "f " + " ".join(form.format(v=i) for i in (1, 2, 3)) + "\n")
    path = tmp_path / "m.obj"
    path.write_text(text)
    fast = read_obj(path.read_bytes())
    assert fast is not None
    v1, f1, n1, uv1 = fast
    v2, f2, n2, uv2 = shapes._read_general(path, "obj")
    v2, f2 = np.asarray(v2), np.asarray(f2)
    assert len(f1) == 9  # eight triangles of the grid (four quads split or given as such) and one more
    assert (uv1 is not None) == ("vt" in extra) and (n1 is not None) == ("vn" in extra)
    ours = corners(v1, f1, *(a for a in (uv1, n1) if a is not None))
    theirs = corners(v2, f2, *(a for a, b in ((uv2, uv1), (n2, n1)) if b is not None))
    for a, b in zip(ours, theirs):
        np.testing.assert_array_equal(a, b)


def test_a_uv_seam_gets_a_vertex_per_index_triple():
    """Two faces share a position but not its texture coordinate: the position is split into two vertices,
    numbered in order of first use, each with its own uv (trimesh's reader keeps one uv per position)."""
    data = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvt 0.5 0.5\nf 1/1 2/2 3/3\nf 2/4 4/2 3/3\n"
    v, f, n, uv = read_obj(data)
    assert n is None and len(v) == 5
    np.testing.assert_array_equal(f, [[0, 1, 2], [3, 4, 2]])
    np.testing.assert_array_equal(v[f[1]], [[1, 0, 0], [1, 1, 0], [0, 1, 0]])
    np.testing.assert_array_equal(uv[f[1]], [[0.5, 0.5], [1, 0], [0, 1]])


def test_a_w_coordinate_a_vertex_colour_or_a_trailing_comment_is_ignored():
    """(trimesh's reader refuses a comment after a face's corners.)"""
    v, f, _, _ = read_obj(b"v 0 0 0 1\nv 1 0 0 0.5 0.5 0.5 # red\nv 0 1 0\nf 1 2 3 # one\nf 3 2 1\n")
    np.testing.assert_array_equal(v, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    np.testing.assert_array_equal(f, [[0, 1, 2], [2, 1, 0]])


def test_a_polygon_is_a_fan_around_its_first_corner():
    v, f, _, _ = read_obj(b"v 0 0 0\nv 1 0 0\nv 2 1 0\nv 1 2 0\nv 0 1 0\nf 1 2 3 4 5\nf 1 2 3\n")
    np.testing.assert_array_equal(f, [[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 1, 2]])


def test_relative_indices_and_mixed_corner_forms_are_read_statement_by_statement():
    """Negative indices count back from the statements before the face; a corner without uv gets (0, 0) and
    without a normal leaves the mesh's normals to the faces (as Mitsuba, which loads such a face); `vt u`
    alone has v = 0."""
    v, f, n, uv = read_obj(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 5 5 5\nf -4 -3 -2\n")
    np.testing.assert_array_equal(f, [[0, 1, 2], [0, 1, 2]])
    assert n is None and uv is None
    v, f, n, uv = read_obj(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0.5\nvn 0 0 1\nf 1/1/1 2//1 3\n")
    np.testing.assert_array_equal(v[f[0]], [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    np.testing.assert_array_equal(uv[f[0]], [[0.5, 0], [0, 0], [0, 0]])
    assert n is None


@pytest.mark.parametrize("data", [
    b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n",  # too few corners
    b"v 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",  # a vertex with two coordinates
    b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/0 2/1 3/1\n",  # an index 0
    b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -4 2 3\n",  # back beyond the first vertex
    b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n",  # beyond the vertices
    b"v 0 0 0\nv 1 0 0\nv 0 x 0\nf 1 2 3\n",  # not a number
    b"v 0 0 0\nv 1 0 0\n",  # no faces
])
def test_files_it_cannot_read_go_to_the_general_reader(data):
    assert read_obj(data) is None


def test_reading_a_plain_obj_does_not_import_trimesh(tmp_path):
    """trimesh takes half a second to import; an OBJ the reader reads never needs it."""
    path = tmp_path / "m.obj"
    path.write_text(GRID + quad_faces("{v}", True))
    code = (f"import sys; from probvis.scene.shapes import load_mesh; m = load_mesh({str(path)!r}); "
            "print(len(m.faces), 'trimesh' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["8", "False"]


@pytest.mark.parametrize("text, message", [
    ("v 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "m.obj:1: 'v' needs 3 numbers: 'v 0 0'"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 x\nf 1 2 3\n", "m.obj:3: malformed 'v' statement 'v 0 1 x'"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt\nf 1/1 2/1 3/1\n", "m.obj:4: 'vt' needs 1 number: 'vt'"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 1\nf 1//1 2//1 3//1\n", "m.obj:4: 'vn' needs 3 numbers"),
])
def test_a_statement_short_of_numbers_is_named_with_its_line(tmp_path, text, message):
    from probvis.errors import ProbvisError

    (tmp_path / "m.obj").write_text(text)
    with pytest.raises(ProbvisError, match=message.replace(".", r"\.")):
        shapes.load_mesh(tmp_path / "m.obj")


def test_a_byte_order_mark_does_not_hide_the_first_line():
    """Windows editors start a file with a UTF-8 byte-order mark: the first vertex was skipped and every face
    index shifted by one."""
    from probvis.scene.obj import read_obj

    v, f, _, _ = read_obj(b"\xef\xbb\xbfv 5 5 5\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert v.tolist()[0] == [5, 5, 5] and len(v) == 4 and f.tolist() == [[0, 1, 2]]


def test_a_bare_face_statement_among_faces_is_named(tmp_path):
    """An `f` with no corners was skipped where other faces followed (refused where it was the only one)."""
    from probvis.errors import ProbvisError

    path = tmp_path / "m.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf\nf 1 2 3\n")
    with pytest.raises(ProbvisError, match=r"m.obj:4: a face needs at least 3 vertices: 'f'"):
        shapes.load_mesh(path)


@pytest.mark.parametrize("text", [
    b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    b"v 0 0 0\r\nv 1 0 0\r\nv 0 1 0\r\nf 1 2 3",  # Windows line ends, no last one
    b"v\t0 0 0\nv  1 0 0\nvt\t0.5 0.5\nvn 0 0 1\nv 0 1 0\nf\t1 2 3\n",  # tabs and runs of blanks
    b"  v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",  # an indented statement
    b"v 0 0 0 # origin\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",  # a statement's comment
    b"# v 9 9 9\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",  # a comment line only
    b"v 0 0 0\rv 1 0 0\nv 0 1 0\nf 1 2 3\n",  # a lone carriage return
    b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv\nf 1 2 3\n", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf\n",  # bare statements
    b"v 0 0 0\nvp 0.5\nv 1 0 0\nv 0 1 0\nvt#x\nf 1 2 3\nfo 1\n",  # other keywords that start alike
    b"", b"\n\n", b"v", b"f 1 2 3",
])
def test_statements_read_by_first_bytes_equal_the_expressions(text):
    """The statements told apart by their lines' first bytes are those the regular expressions find, bare
    statements included, on every layout the fast way handles and those it leaves to the expressions."""
    from probvis.scene import obj

    bodies, bare = obj._statements(text)
    data = text.replace(b"\r\n", b"\n")
    assert bare == (obj._BARE.search(data) is not None)
    for name in obj._KINDS:
        found = obj._STATEMENT[name].findall(data)
        assert [b.strip() for b in bodies[name.decode()]] == [b.strip() for b in found]
