"""Our images against Mitsuba 3 (scalar_rgb) on small scenes written here: same settings, same error."""
import pytest
import trimesh

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
