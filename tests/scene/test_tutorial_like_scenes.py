"""Scenes written the way Mitsuba 3's tutorials write theirs (`cbox.xml`: path integrator, tent filter, clip
planes and a focus distance on a perspective sensor, glass and mirror spheres; `simple.xml`: no field of view,
a PLY mesh, two point lights): they load unchanged, warn only about what is approximated, and render Mitsuba's
direct illumination."""
import warnings

import numpy as np
import pytest
import trimesh

import probvis
from tests.conftest import assert_matches_mitsuba, write_scene

QUADS = {  # the Cornell box's walls as one-quad OBJ files, in the tutorial's [-1, 1]^3 frame
    "floor": "-1 -1 1  1 -1 1  1 -1 -1  -1 -1 -1", "ceiling": "1 1 -1  1 1 1  -1 1 1  -1 1 -1",
    "back": "1 -1 -1  1 1 -1  -1 1 -1  -1 -1 -1", "greenwall": "-1 1 -1  -1 1 1  -1 -1 1  -1 -1 -1",
    "redwall": "1 -1 1  1 1 1  1 1 -1  1 -1 -1", "luminaire": "0.25 1 -0.25  0.25 1 0.25  -0.25 1 0.25  -0.25 1 -0.25",
}
CBOX = """
<default name="spp" value="16"/><default name="res" value="48"/><default name="max_depth" value="6"/>
<default name="integrator" value="path"/>
{integrator}
<sensor type="perspective" id="sensor">
    <string name="fov_axis" value="smaller"/><float name="near_clip" value="0.001"/>
    <float name="far_clip" value="100.0"/><float name="focus_distance" value="1000"/>
    <float name="fov" value="39.3077"/>
    <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
    <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
    <film type="hdrfilm"><integer name="width" value="$res"/><integer name="height" value="$res"/>
        <rfilter type="{filter}"/></film>
</sensor>
<bsdf type="diffuse" id="white"><rgb name="reflectance" value="0.885809, 0.698859, 0.666422"/></bsdf>
<bsdf type="diffuse" id="green"><rgb name="reflectance" value="0.105421, 0.37798, 0.076425"/></bsdf>
<bsdf type="diffuse" id="red"><rgb name="reflectance" value="0.570068, 0.0430135, 0.0443706"/></bsdf>
{glass}
{mirror}
<shape type="obj" id="light"><string name="filename" value="meshes/luminaire.obj"/>
    <transform name="to_world"><translate y="-0.01"/></transform><ref id="white"/>
    <emitter type="area"><rgb name="radiance" value="18.387, 13.9873, 6.75357"/></emitter></shape>
{walls}
<shape type="sphere" id="mirrorsphere"><transform name="to_world"><scale value="0.5"/>
    <translate x="-0.3" y="-0.5" z="0.2"/></transform><ref id="mirror"/></shape>
<shape type="sphere" id="glasssphere"><transform name="to_world"><scale value="0.25"/>
    <translate x="0.5" y="-0.75" z="-0.2"/></transform><ref id="glass"/></shape>
"""
SIMPLE = """
<default name="spp" value="16"/><default name="res" value="40"/>
<integrator type="path"/>
<sensor type="perspective" id="sensor">
    <transform name="to_world"><lookat target="0, 0, 1.25" origin="0, -12, 5" up="0, 0, 1"/></transform>
    <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
    <film type="hdrfilm"><rfilter type="box"/><integer name="width" value="$res"/>
        <integer name="height" value="$res"/></film>
</sensor>
<shape type="ply" id="teapot"><string name="filename" value="meshes/blob.ply"/>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.9 0.9 0.0"/></bsdf></shape>
<shape type="rectangle"><transform name="to_world"><scale value="6"/></transform></shape>
<emitter type="point" id="light1"><point name="position" x="2" y="-6.0" z="4.5"/><rgb name="intensity" value="10.0"/>
</emitter>
<emitter type="point" id="light2"><point name="position" x="-3" y="-3.0" z="-0.5"/><rgb name="intensity" value="1.0"/>
</emitter>
"""


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    d = tmp_path_factory.mktemp("tutorial")
    (d / "meshes").mkdir()
    for name, corners in QUADS.items():
        v = np.array(corners.split(), float).reshape(4, 3)
        (d / "meshes" / f"{name}.obj").write_text("".join(f"v {x} {y} {z}\n" for x, y, z in v) + "f 1 2 3 4\n")
    blob = trimesh.creation.icosphere(subdivisions=3)
    blob.vertices *= [1.5, 1.0, 1.2]
    blob.vertices += [0.0, 0.0, 1.3]
    blob.export(d / "meshes" / "blob.ply")
    return d


PATH = '<integrator type="$integrator"><integer name="max_depth" value="$max_depth"/></integrator>'
DIRECT = ('<integrator type="direct"><integer name="emitter_samples" value="1"/><integer name="bsdf_samples" value="0"/>'
          '</integrator>')


def cbox(folder, name="cbox.xml", glass='<bsdf type="dielectric" id="glass"/>',
         mirror='<bsdf type="conductor" id="mirror"/>', integrator=PATH, rfilter="tent"):
    walls = "\n".join(f'<shape type="obj"><string name="filename" value="meshes/{w}.obj"/>'
                      f'<ref id="{"green" if w == "greenwall" else "red" if w == "redwall" else "white"}"/></shape>'
                      for w in ("floor", "ceiling", "back", "greenwall", "redwall"))
    text = CBOX
    for key, value in (("walls", walls), ("glass", glass), ("mirror", mirror), ("integrator", integrator),
                       ("filter", rfilter)):
        text = text.replace("{" + key + "}", value)
    return write_scene(folder / name, text)


def test_cbox_loads_unchanged_warning_only_about_approximations(folder):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = probvis.load_scene(cbox(folder))
    messages = sorted(str(w.message).split(": ", 1)[1] for w in caught)
    assert len(messages) == 3, messages
    assert messages[0].startswith("bsdf 'conductor' rendered as diffuse")
    assert messages[1].startswith("bsdf 'dielectric' rendered as diffuse")
    assert messages[2].startswith("integrator 'path' rendered as its direct-illumination component")
    assert scene.camera.near_clip == 0.001 and scene.camera.rfilter == "tent"
    assert scene.defaults.spp == 16


def test_cbox_with_its_appearance_in_the_subset_matches_mitsuba(folder):
    """The glass and mirror swapped for the diffuse colours probvis gives them, in both renderers (and a box
    filter: the tent's expected image is Mitsuba's too, tests/test_cameras.py, but filter importance sampling
    is noisier than Mitsuba's splatting where a visible emitter's edge crosses a pixel)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        glass, mirror = (probvis.load_scene(cbox(folder)).reflectance[k] for k in (3, 4))
    glass, mirror = (f'<bsdf type="diffuse" id="{i}"><rgb name="reflectance" value="{", ".join(map(str, c))}"/></bsdf>'
                     for i, c in (("glass", glass), ("mirror", mirror)))
    path = cbox(folder, "cbox-diffuse.xml", glass, mirror, DIRECT, "box")
    assert_matches_mitsuba(path, shadow_rays=1)


def test_simple_loads_unchanged_and_matches_mitsuba(folder):
    """No field of view (Mitsuba's 50 mm focal length), a PLY mesh, two point lights."""
    path = write_scene(folder / "simple.xml", SIMPLE)
    with pytest.warns(UserWarning, match="integrator 'path' rendered as its direct-illumination component"):
        scene = probvis.load_scene(path)
    assert scene.n_emitters == 2
    direct = path.read_text().replace('<integrator type="path"/>', '<integrator type="direct"><integer '
                                      'name="emitter_samples" value="1"/><integer name="bsdf_samples" value="0"/>'
                                      '</integrator>')
    assert_matches_mitsuba(write_scene(folder / "simple-direct.xml", direct.split("\n", 2)[2].rsplit("</scene>")[0]),
                           shadow_rays=1)
