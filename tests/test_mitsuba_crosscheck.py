"""Our images against Mitsuba 3 (scalar_rgb) on small scenes written here: same settings, same error."""
import numpy as np
import pytest
import trimesh

import probvis

from tests.conftest import assert_matches_mitsuba, sensor, write_scene

pytest.importorskip("mitsuba")


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory):
    d = tmp_path_factory.mktemp("xcheck")
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.35)
    ball.export(d / "ball.obj")
    body = sensor(origin="0.3, -2.6, 1.6", target="0, 0, 0.3", up="0, 0, 1", fov=45, spp="$spp", sr=4,
                  w=40, h=32) + """
    <bsdf type="diffuse" id="floor"><rgb name="reflectance" value="0.7, 0.6, 0.5"/></bsdf>
    <shape type="rectangle"><transform name="to_world"><scale value="2"/></transform><ref id="floor"/></shape>
    <shape type="cube"><transform name="to_world"><scale x="0.25" y="0.4" z="0.3"/>
        <rotate z="1" angle="30"/><translate x="-0.5" y="0.2" z="0.3"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.6, 0.3"/></bsdf></shape>
    <shape type="obj"><string name="filename" value="ball.obj"/><boolean name="face_normals" value="true"/>
        <transform name="to_world"><translate x="0.5" y="-0.1" z="0.5"/></transform>
        <bsdf type="twosided"><bsdf type="diffuse"><rgb name="reflectance" value="0.8, 0.3, 0.3"/></bsdf></bsdf>
    </shape>
    <shape type="rectangle"><transform name="to_world"><scale x="0.4" y="0.25"/><rotate x="1" angle="160"/>
        <translate x="0.2" y="0.3" z="1.6"/></transform>
        <emitter type="area"><rgb name="radiance" value="12, 10, 8"/></emitter></shape>
    <shape type="rectangle"><transform name="to_world"><scale x="0.15" y="0.15"/><rotate y="1" angle="120"/>
        <translate x="-1.2" y="-0.4" z="0.9"/></transform>
        <emitter type="area"><rgb name="radiance" value="4, 6, 12"/></emitter></shape>"""
    return write_scene(d / "xcheck.xml", body, '<default name="spp" value="16"/>')


def test_matches_mitsuba_at_equal_settings(scene_file):
    """Two emitters of different power (we choose by power, Mitsuba uniformly): same image, no more error."""
    assert_matches_mitsuba(scene_file, reference_spp=1024)


@pytest.mark.parametrize("normal", ["0 -1 0", "0 1 0"])
def test_a_mesh_emitter_emits_towards_its_vertex_normals(tmp_path, normal):
    """A quad light whose faces wind upwards but whose vertex normals point down (an exporter that reversed the
    faces and kept the normals) lit nothing below it while looking lit from below, and the reverse: Mitsuba
    emits towards the shading normals, both into the scene (the floor against Mitsuba's image) and as seen
    directly (its radiance exactly, from below)."""
    (tmp_path / "light.obj").write_text("v -0.3 1.9 -0.3\nv 0.3 1.9 -0.3\nv 0.3 1.9 0.3\nv -0.3 1.9 0.3\n"
                                        f"vn {normal}\nf 1//1 3//1 2//1\nf 1//1 4//1 3//1\n")
    shapes = """
    <shape type="rectangle"><transform name="to_world"><scale value="3"/><rotate x="1" angle="-90"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.8"/></bsdf></shape>
    <shape type="obj"><string name="filename" value="light.obj"/>
        <emitter type="area"><rgb name="radiance" value="10"/></emitter></shape>"""
    below = write_scene(tmp_path / "below.xml", sensor(origin="0, 0.5, 0", target="0, 1.9, 0", up="0, 0, 1",
                                                       fov=10) + shapes)
    seen = probvis.render(below, spp=4, shadow_rays=4, seed=1).image
    floor = write_scene(tmp_path / "floor.xml", sensor(origin="0, 1, 5", target="0, 0.2, 0", fov=30, spp="$spp")
                        + shapes, '<default name="spp" value="16"/>')
    if normal == "0 1 0":  # emitting upwards, away from everything: black from below and on the floor
        assert not seen.any() and not probvis.render(floor, spp=4, shadow_rays=4, seed=1).image.any()
        return
    np.testing.assert_array_equal(seen, 10.0)
    assert_matches_mitsuba(floor, reference_spp=1024)
