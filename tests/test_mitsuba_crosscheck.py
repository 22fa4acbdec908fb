"""Our images against Mitsuba 3 (scalar_rgb) on small scenes written here: same settings, same error."""
import numpy as np
import pytest
import trimesh

import probvis
from tests.conftest import relmse, sensor, write_scene

mi = pytest.importorskip("mitsuba")


def mitsuba_render(path, spp, seed):
    mi.set_variant("scalar_rgb")
    scene = mi.load_file(str(path), spp=spp)
    return np.array(mi.render(scene, seed=seed, spp=spp), dtype=np.float64)


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
    ref = mitsuba_render(scene_file, 1024, seed=100)
    theirs = [relmse(mitsuba_render(scene_file, 16, seed=s), ref) for s in (1, 2)]
    ours = probvis.render(scene_file, spp=16, shadow_rays=4, seed=1).image
    assert relmse(ours, ref) <= 1.5 * np.mean(theirs)
    np.testing.assert_allclose(ours.reshape(-1, 3).mean(0), ref.reshape(-1, 3).mean(0), rtol=0.01)
