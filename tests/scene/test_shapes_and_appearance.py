"""Mitsuba shapes beyond meshes (disk, cylinder) against Mitsuba 3, and appearance probvis approximates:
one warning per plugin type naming file:line, or an error with --strict."""
import re
import warnings

import numpy as np
import pytest

import probvis
from probvis import ProbvisError
from probvis.cli import main
from tests.conftest import assert_matches_mitsuba, sensor, write_scene

SHAPES = """
    <shape type="disk"><transform name="to_world"><scale value="2"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.6, 0.5"/></bsdf></shape>
    <shape type="cylinder"><float name="radius" value="0.15"/><point name="p0" x="-0.3" y="0.1" z="0"/>
        <point name="p1" x="-0.1" y="0.2" z="0.9"/>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.6, 0.3"/></bsdf></shape>
    <shape type="cylinder"><float name="radius" value="0.3"/><boolean name="flip_normals" value="true"/>
        <transform name="to_world"><translate x="0.6" y="-0.2"/></transform>
        <bsdf type="twosided"><bsdf type="diffuse"/></bsdf></shape>
    <shape type="disk"><transform name="to_world"><scale value="0.35"/><rotate x="1" angle="170"/>
        <translate x="0.1" y="0.2" z="1.8"/></transform>
        <emitter type="area"><rgb name="radiance" value="14, 12, 9"/></emitter></shape>"""


def test_disk_and_cylinder_match_mitsuba(tmp_path):
    path = write_scene(tmp_path / "shapes.xml", sensor(origin="0.3, -2.8, 1.7", target="0, 0, 0.3", up="0, 0, 1",
                                                        fov=45, spp="$spp", w=40, h=32) + SHAPES,
                       '<default name="spp" value="16"/>')
    assert_matches_mitsuba(path)


@pytest.mark.parametrize("side, colour", [("1.5", 0), ("-1.5", 1)])
def test_a_twosided_pair_shows_its_front_and_its_back_as_in_mitsuba(tmp_path, side, colour):
    """Mitsuba's twosided with two BSDFs: the first seen from the front, the second from behind, each lit from its
    own side (probvis refused the pair); the image against Mitsuba's, red from above and green from below."""
    head = sensor(origin=f"0.4, 0.3, {side}", target="0, 0, 0", up="0, 1, 0", fov=60, spp="$spp", w=24, h=24,
                  sr=1)  # Mitsuba 3.9's direct integrator multiplies a point light by its emitter_samples
    body = f"""<shape type="rectangle"><bsdf type="twosided"><bsdf type="diffuse"><rgb name="reflectance"
        value="0.8, 0.1, 0.1"/></bsdf><bsdf type="diffuse"><texture type="checkerboard" name="reflectance">
        <rgb name="color0" value="0.1, 0.7, 0.2"/><rgb name="color1" value="0.1, 0.5, 0.1"/></texture></bsdf>
        </bsdf></shape><emitter type="point"><point name="position" x="-0.3" y="0.2" z="{float(side) * 0.8}"/>
        <rgb name="intensity" value="3"/></emitter>"""
    path = write_scene(tmp_path / "two.xml", head + body, '<default name="spp" value="16"/>')
    assert_matches_mitsuba(path, shadow_rays=1)
    image = probvis.render(path, spp=4).image.reshape(-1, 3).mean(0)
    assert image.argmax() == colour


APPROXIMATED = """
    <bsdf type="plastic" id="p"><rgb name="diffuse_reflectance" value="0.1, 0.27, 0.36"/></bsdf>
    <shape type="rectangle"><transform name="to_world"><scale value="2"/></transform><ref id="p"/></shape>
    <shape type="cube"><transform name="to_world"><scale value="0.2"/></transform><ref id="p"/></shape>
    <shape type="sphere"><float name="radius" value="0.2"/><point name="center" x="0.5" y="0" z="0.3"/>
        <bsdf type="dielectric"><float name="int_ior" value="1.5"/></bsdf></shape>
    <shape type="disk"><transform name="to_world"><translate x="-0.6" z="0.01"/></transform>
        <bsdf type="blendbsdf"><float name="weight" value="0.25"/><bsdf type="diffuse"><rgb name="reflectance"
        value="0.8"/></bsdf><bsdf type="roughconductor"/></bsdf></shape>
    <shape type="rectangle"><transform name="to_world"><scale value="0.3"/><rotate x="1" angle="180"/>
        <translate z="2"/></transform><emitter type="area"><rgb name="radiance" value="10"/></emitter></shape>"""


def test_approximated_appearance_warns_once_per_plugin_type(tmp_path):
    path = write_scene(tmp_path / "a.xml", sensor() + APPROXIMATED)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = probvis.load_scene(path)
    messages = [str(w.message) for w in caught]
    assert len(messages) == 4, messages  # plastic (used twice), dielectric, blendbsdf and the conductor in it
    assert any(m.startswith(f"{path}:") and "bsdf 'plastic' rendered as diffuse with reflectance 0.1, 0.27, 0.36"
               in m for m in messages)
    colours = {tuple(np.round(c, 4)) for c in scene.reflectance}
    eta = 1.5 / 1.000277  # glass in air (Mitsuba's default ext_ior): Fresnel reflectance at normal incidence
    assert (round(((eta - 1) / (eta + 1)) ** 2, 4),) * 3 in colours
    assert (0.85, 0.85, 0.85) in colours  # 3/4 of a 0.8 diffuse and 1/4 of a white conductor


def test_strict_refuses_approximated_appearance(tmp_path, capsys):
    path = write_scene(tmp_path / "a.xml", sensor() + APPROXIMATED)
    with pytest.raises(ProbvisError, match=r"a.xml:\d+: <bsdf>: bsdf 'plastic' is approximated"):
        probvis.load_scene(path, strict=True)
    assert main(["render", str(path), "--strict", "-o", str(tmp_path / "o.exr")]) == 2
    assert "drop --strict" in capsys.readouterr().err and not (tmp_path / "o.exr").exists()


def write_serialized(path, meshes, version=4):
    """A Mitsuba .serialized file of `meshes` [(vertices, faces, normals or None[, uv])], written from the format's
    description (little endian; a zlib stream per mesh after a 4-byte header; an offset table at the end)."""
    import struct
    import zlib

    out, offsets = bytearray(), []
    for k, (v, f, n, *uv) in enumerate(meshes):
        uv = uv[0] if uv else None
        offsets.append(len(out))
        body = struct.pack("<I", 0x2000 | (0x0001 if n is not None else 0) | (0x0002 if uv is not None else 0))
        if version == 4:
            body += f"mesh{k}".encode() + b"\0"
        body += struct.pack("<QQ", len(v), len(f)) + np.asarray(v, "<f8").tobytes()
        if n is not None:
            body += np.asarray(n, "<f8").tobytes()
        if uv is not None:
            body += np.asarray(uv, "<f8").tobytes()
        body += np.asarray(f, "<u4").tobytes()
        out += struct.pack("<HH", 0x041C, version) + zlib.compress(body)
    out += b"".join(struct.pack("<Q" if version == 4 else "<I", o) for o in offsets)
    out += struct.pack("<I", len(meshes))
    path.write_bytes(bytes(out))
    return path


TETRA = (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]), np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]),
         None)


@pytest.mark.parametrize("version", [3, 4])
def test_serialized_meshes_by_shape_index(tmp_path, version):
    from probvis.scene import serialized, shapes

    box_v, box_f = shapes.cube()
    path = write_serialized(tmp_path / "m.serialized", [(box_v, box_f, None), TETRA], version)
    v, f, n, _ = serialized.load_serialized(path, 1)
    np.testing.assert_array_equal(v, TETRA[0])
    np.testing.assert_array_equal(f, TETRA[1])
    v, f, _, _ = serialized.load_serialized(path, 0)
    assert len(f) == 12
    with pytest.raises(ProbvisError, match="shape_index 2 is out of range"):
        serialized.load_serialized(path, 2)
    bad = tmp_path / "bad.serialized"
    bad.write_bytes(b"\x1c\x04\x09\x00" + b"\0" * 16)
    with pytest.raises(ProbvisError, match="serialized format version 9 is not supported"):
        serialized.load_serialized(bad)


def test_serialized_vertex_attributes_are_checked_as_obj_and_ply_ones(tmp_path):
    """NaN or zero normals and NaN or huge uv in a serialized mesh (black or NaN images before) are refused, naming
    the mesh and the vertex; an OBJ's huge vt names its line."""
    from probvis.scene import serialized, shapes

    v, f, _ = TETRA
    good_n, good_uv = np.ones((4, 3)), np.zeros((4, 2))
    assert serialized.load_serialized(write_serialized(tmp_path / "ok.serialized", [(v, f, good_n, good_uv)]))
    for n, uv, message in ((np.where(np.eye(4, 3, 1) > 0, np.nan, 1.0), None, r"zero vertex normals \(vertex 0\)"),
                           (np.zeros((4, 3)), None, r"zero vertex normals \(vertex 0\)"),
                           (good_n, np.where(np.eye(4, 2, -2) > 0, np.nan, 0.0),
                            r"huge texture coordinates .* \(vertex 2\)"),
                           (good_n, np.where(np.eye(4, 2, -3) > 0, 1e300, 0.0), r"huge texture .* \(vertex 3\)")):
        path = write_serialized(tmp_path / "m.serialized", [(v, f, n, uv)])
        with pytest.raises(ProbvisError, match="mesh 0 of .*m.serialized has NaN, infinite or " + message):
            serialized.load_serialized(path)
    obj = tmp_path / "m.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1e300 1\nf 1/1 2/2 3/3\n")
    with pytest.raises(ProbvisError, match=r"m.obj:6: mesh m.obj has NaN, infinite or huge texture coordinates"):
        shapes.load_mesh(obj)


def test_corrupt_serialized_tables_and_streams_are_named(tmp_path):
    """A corrupt offset table was a struct.error traceback; megabytes of zeros after a valid mesh were all
    decompressed (3 GiB in the sweep): only the bytes the mesh's header declares are."""
    import struct
    import tracemalloc
    import zlib

    from probvis.scene import serialized

    good = write_serialized(tmp_path / "m.serialized", [TETRA, TETRA]).read_bytes()
    for name, data, message in (
            ("count", good[:-4] + struct.pack("<I", 10 ** 9), "its table lists 1000000000 meshes"),
            ("offset", good[:-12] + struct.pack("<Q", 10 ** 12) + good[-4:], "mesh 1 starts at byte 1000000000000"),
            ("counts", good[:4] + zlib.compress(struct.pack("<I", 0x2000) + b"m\0" + struct.pack("<QQ", 2**40, 1))
             + struct.pack("<QI", 0, 1), "it declares 1099511627776 vertices and 1 triangles"),
            ("short", good[:4] + zlib.compress(struct.pack("<I", 0x2000) + b"m\0" + struct.pack("<QQ", 400, 1))
             + struct.pack("<QI", 0, 1), "but its data ends after")):
        path = tmp_path / f"{name}.serialized"
        path.write_bytes(data)
        with pytest.raises(ProbvisError, match=re.escape(message)):
            serialized.load_serialized(path, 1 if name == "offset" else 0)
    v, f, _ = TETRA
    body = struct.pack("<I", 0x2000) + b"m\0" + struct.pack("<QQ", len(v), len(f)) + np.asarray(v, "<f8").tobytes() \
        + np.asarray(f, "<u4").tobytes()
    padded = tmp_path / "padded.serialized"
    padded.write_bytes(struct.pack("<HH", 0x041C, 4) + zlib.compress(body + bytes(64 << 20)) + struct.pack("<QI", 0, 1))
    tracemalloc.start()
    try:
        _, faces, _, _ = serialized.load_serialized(padded)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    np.testing.assert_array_equal(faces, f)
    assert peak < 16 << 20  # the file (64 KiB) and its mesh, not the 64 MiB of zeros after it


def test_serialized_shapegroups_and_instances_match_mitsuba(tmp_path):
    """A serialized mesh instanced twice through a shapegroup, against Mitsuba's render of the same file."""
    from probvis.scene import shapes

    box_v, box_f = shapes.cube()
    write_serialized(tmp_path / "m.serialized", [(box_v, box_f, None), TETRA])
    body = sensor(origin="0.3, -2.8, 1.7", target="0, 0, 0.3", up="0, 0, 1", fov=45, spp="$spp", w=40, h=32) + """
    <shape type="rectangle"><transform name="to_world"><scale value="2"/></transform><bsdf type="diffuse"/></shape>
    <shape type="shapegroup" id="g">
        <shape type="serialized"><string name="filename" value="m.serialized"/><integer name="shape_index" value="1"/>
            <boolean name="face_normals" value="true"/><transform name="to_world"><scale value="0.4"/></transform>
            <bsdf type="twosided"><bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.6, 0.3"/></bsdf></bsdf>
        </shape></shape>
    <shape type="instance"><ref id="g"/><transform name="to_world"><translate x="-0.5"/></transform></shape>
    <shape type="instance"><ref id="g"/><transform name="to_world"><rotate z="1" angle="40"/><translate x="0.4"
        y="0.2" z="0.2"/></transform></shape>
    <shape type="disk"><transform name="to_world"><scale value="0.35"/><rotate x="1" angle="170"/>
        <translate x="0.1" y="0.2" z="1.8"/></transform>
        <emitter type="area"><rgb name="radiance" value="14, 12, 9"/></emitter></shape>"""
    path = write_scene(tmp_path / "inst.xml", body, '<default name="spp" value="16"/>')
    scene = probvis.load_scene(path)
    assert scene.n_triangles == 2 + 2 * 4 + shapes.DISK_SEGMENTS
    assert_matches_mitsuba(path)


@pytest.mark.parametrize("spectrum", ["400:0.2, 500:0.8, 600:0.4, 700:0.1", "450:0.9, 550:0.1, 650:0.5",
                                      "380:0.05 480:0.3 580:0.95 680:0.6 780:0.2"])
def test_sampled_spectra_reduce_to_mitsubas_rgb(tmp_path, spectrum):
    """A reflectance under D65 (clamped), an emitter's radiance and a point light's intensity as is, within
    2e-3 of Mitsuba's own reduction (its CIE tables and ours differ in the last digits)."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    body = f"""
    <shape type="rectangle"><bsdf type="diffuse"><spectrum name="reflectance" value="{spectrum}"/></bsdf></shape>
    <shape type="rectangle"><transform name="to_world"><translate z="1"/></transform>
        <emitter type="area"><spectrum name="radiance" value="{spectrum}"/></emitter></shape>
    <emitter type="point"><spectrum name="intensity" value="{spectrum}"/></emitter>"""
    scene = probvis.load_scene(write_scene(tmp_path / "spectra.xml", sensor() + body))
    pairs = [p.split(":") for p in spectrum.replace(",", " ").split()]
    w, v = [float(a) for a, _ in pairs], [float(b) for _, b in pairs]
    reflectance = np.array(mi.spectrum_list_to_srgb(w, v, True, True))
    emission = np.array(mi.spectrum_list_to_srgb(w, v, False, False))
    np.testing.assert_allclose(scene.reflectance[scene.tri_material[0]], reflectance, atol=2e-3)
    np.testing.assert_allclose(scene.emitter_radiance, [emission, emission], atol=2e-3)
    bad = write_scene(tmp_path / "bad.xml", sensor() + body.replace(spectrum, "500:0.2, 400:0.3", 1))
    with pytest.raises(ProbvisError, match="bad.xml:.*increasing wavelengths"):
        probvis.load_scene(bad)


def test_a_single_value_spectrum_is_flat_emission_or_grey_reflectance_as_in_mitsuba(tmp_path):
    """`<spectrum value="5"/>` on an emitter is a flat emission spectrum (illuminant E), whose RGB Mitsuba's RGB
    variants read as (1.205, 0.948, 0.909) x 5, not a grey 5; on a reflectance it stays grey."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    body = """
    <shape type="rectangle"><bsdf type="diffuse"><spectrum name="reflectance" value="0.5"/></bsdf></shape>
    <shape type="rectangle"><transform name="to_world"><translate z="1"/></transform>
        <emitter type="area"><spectrum name="radiance" value="5"/></emitter></shape>
    <emitter type="point"><spectrum name="intensity" value="5"/></emitter>"""
    scene = probvis.load_scene(write_scene(tmp_path / "flat.xml", sensor() + body))
    theirs = mi.load_string('<emitter version="3.0.0" type="constant"><spectrum name="radiance" value="5"/>'
                            '</emitter>')
    emission = np.array(mi.traverse(theirs)["radiance.value"])
    assert not np.allclose(emission, emission[0])
    np.testing.assert_allclose(scene.emitter_radiance, [emission, emission], rtol=1e-3)
    np.testing.assert_allclose(scene.reflectance[scene.tri_material[0]], 0.5)


def test_vertex_normals_weigh_faces_by_their_angle_at_the_vertex():
    """Where a mesh has no normals: at a vertex, the unit sum of its faces' normals times their corner angles
    (here 90° in the z = 0 plane and 45° in the x = 0 plane); a vertex without faces gets zero."""
    from probvis.scene.mesh_geometry import angle_weighted_normals

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 1, 1], [5, 5, 5]], float)
    f = np.array([[0, 1, 2], [0, 3, 2]])
    fn = np.array([[0, 0, 1.0], [1.0, 0, 0]])
    n = angle_weighted_normals(v, f, fn)
    want = np.pi / 2 * fn[0] + np.pi / 4 * fn[1]
    np.testing.assert_allclose(n[0], want / np.linalg.norm(want), rtol=1e-12)
    np.testing.assert_allclose(n[1], fn[0], rtol=1e-12)
    np.testing.assert_array_equal(n[4], 0.0)


TILTED = [0.5, 0.0, 1.0]  # a shading normal 27 degrees from the floor's geometric one
FLOOR_OBJ = ("v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\n" + "vn {} {} {}\n".format(*TILTED) * 4
             + "f 1//1 2//2 3//3\nf 1//1 3//3 4//4\n")
FLOOR_PLY = ("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
             "property float nx\nproperty float ny\nproperty float nz\nelement face 2\n"
             "property list uchar int vertex_indices\nend_header\n"
             + "".join(f"{x} {y} 0 {TILTED[0]} {TILTED[1]} {TILTED[2]}\n"
                       for x, y in ((-1, -1), (1, -1), (1, 1), (-1, 1)))
             + "3 0 1 2\n3 0 2 3\n")


@pytest.mark.parametrize("kind, text", [("obj", FLOOR_OBJ), ("ply", FLOOR_PLY)])
def test_a_mesh_files_vertex_normals_shade_it_as_in_mitsuba(tmp_path, kind, text):
    """Normals stored in an OBJ (`vn`) or PLY (`nx ny nz`) file are the mesh's shading normals, as Mitsuba's: a
    floor whose stored normals lean away from its geometric normal is shaded by them (computed normals would
    give the flat floor's image, a third brighter here)."""
    (tmp_path / f"floor.{kind}").write_text(text)
    light = """<shape type="rectangle"><transform name="to_world"><scale value="0.5"/><rotate x="1" angle="180"/>
        <translate x="-1" z="2"/></transform><emitter type="area"><rgb name="radiance" value="8"/></emitter></shape>"""
    path = write_scene(tmp_path / "s.xml", sensor(origin="0, 0, 3", spp="$spp") + light +
                       f'<shape type="{kind}"><string name="filename" value="floor.{kind}"/></shape>',
                       '<default name="spp" value="16"/>')
    mesh = probvis.load_scene(path)
    np.testing.assert_allclose(mesh.vertex_normals[-2:].reshape(-1, 3),
                               np.tile(np.array(TILTED) / np.linalg.norm(TILTED), (6, 1)), rtol=1e-6)
    assert_matches_mitsuba(path)


def test_zero_or_nan_vertex_normals_in_a_file_are_an_error_naming_it(tmp_path):
    from probvis.scene.shapes import load_mesh

    for name, bad in (("zero.obj", "0 0 0"), ("nan.obj", "nan 0 1")):
        (tmp_path / name).write_text(FLOOR_OBJ.replace("0.5 0.0 1.0", bad, 1))
        line = FLOOR_OBJ.split("0.5 0.0 1.0")[0].count("\n") + 1
        with pytest.raises(ProbvisError, match=f"{name}:{line}: mesh {name} has NaN, infinite or zero vertex normals"):
            load_mesh(tmp_path / name)
