"""Reading Mitsuba XML: transforms as Mitsuba composes them, defaults, semantics, and clear errors."""
import importlib.util
import os
import re
import warnings

import numpy as np
import pytest

import probvis
from probvis import ProbvisError
from probvis.scene import mitsuba_xml, shapes, transform as tf
from tests.conftest import sensor, write_scene

LIGHT = """<shape type="rectangle"><transform name="to_world"><translate z="2"/></transform>
    <emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>"""


def test_transforms_match_mitsuba():
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    T = mi.ScalarTransform4f
    ours = tf.translate([1, 2, 3]) @ tf.rotate([0.3, -1, 0.2], 37) @ tf.scale([2, 0.5, 1.5])
    theirs = T().translate([1, 2, 3]) @ T().rotate([0.3, -1, 0.2], 37) @ T().scale([2, 0.5, 1.5])
    np.testing.assert_allclose(ours, np.array(theirs.matrix), atol=1e-6)
    ours = tf.look_at([1, 2, 3], [0, 0.5, -1], [0, 1, 0])
    theirs = T().look_at(origin=[1, 2, 3], target=[0, 0.5, -1], up=[0, 1, 0])
    np.testing.assert_allclose(ours, np.array(theirs.matrix), atol=1e-6)


def test_document_order_composition_and_defaults(tmp_path):
    body = sensor(spp="$spp") + """
    <bsdf type="diffuse" id="grey"><rgb name="reflectance" value="0.2, 0.4, 0.6"/></bsdf>
    <shape type="rectangle" id="floor">
        <transform name="to_world"><scale x="2" y="1" z="1"/><rotate x="1" angle="90"/><translate z="$z"/></transform>
        <ref id="grey"/>
    </shape>""" + LIGHT
    path = write_scene(tmp_path / "s.xml", body, '<default name="spp" value="8"/><default name="z" value="-1"/>')
    s = probvis.load_scene(path)
    assert s.defaults.spp == 8 and s.defaults.shadow_rays == 4
    floor = s.triangles[: s.shapes[0].n_triangles].reshape(-1, 3)
    # scale, then rotate about x by 90 (y -> z), then translate z by -1
    assert np.allclose(floor[:, 1], 0.0) and np.isclose(np.abs(floor[:, 0]).max(), 2.0)
    assert np.allclose(np.abs(floor[:, 2] + 1.0), 1.0)
    np.testing.assert_allclose(s.reflectance[s.tri_material[0]], [0.2, 0.4, 0.6])
    s2 = probvis.load_scene(path, spp=3, z=5)
    assert s2.defaults.spp == 3 and np.isclose(s2.triangles[: 2].reshape(-1, 3)[:, 2].mean(), 5.0)


def test_rectangle_faces_plus_z_and_emitter_is_attached(tmp_path):
    path = write_scene(tmp_path / "s.xml", sensor() + LIGHT)
    s = probvis.load_scene(path)
    n = np.cross(s.triangles[:, 1] - s.triangles[:, 0], s.triangles[:, 2] - s.triangles[:, 0])
    assert np.all(n[:, 2] > 0)
    assert s.n_emitters == 1 and np.all(s.tri_emitter == 0)
    # an emitter without a <bsdf> reflects nothing, as in Mitsuba (a black diffuse BSDF)
    assert not s.twosided[s.tri_material[0]] and np.allclose(s.reflectance[s.tri_material[0]], 0.0)


def test_mirroring_transform_keeps_rectangle_normal_like_mitsuba(tmp_path):
    body = sensor() + """<shape type="rectangle"><transform name="to_world"><scale x="-1"/></transform>
        <emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>"""
    s = probvis.load_scene(write_scene(tmp_path / "s.xml", body))
    n = np.cross(s.triangles[:, 1] - s.triangles[:, 0], s.triangles[:, 2] - s.triangles[:, 0])
    assert np.all(n[:, 2] > 0)  # inverse-transpose of +z under a mirror in x is still +z



@pytest.mark.parametrize("mirror", ["<scale x='-1'/>", "<scale value='-2'/>", "<scale y='-1' z='-1'/>"])
def test_a_mirrored_cube_faces_outward_like_mitsuba_s(tmp_path, mirror):
    """Mitsuba's cube is a mesh with its normals, which the mirror transforms as normals: it still faces outward
    (its emitter lights the scene). probvis turned it inside out (10% darker, a mirrored cube emitter black)."""
    body = sensor() + f"""<shape type="cube"><transform name="to_world">{mirror}</transform>
        <emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>"""
    s = probvis.load_scene(write_scene(tmp_path / "s.xml", body))
    t = s.triangles
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    assert np.all(np.einsum("ij,ij->i", n, t.mean(axis=1)) > 0)

MIRROR = "<transform name='to_world'><scale x='-1'/><translate x='-1.2'/></transform>"


@pytest.mark.parametrize("kind", ["sphere", "cylinder", "obj"])
@pytest.mark.parametrize("where, inside_out", [("own", {"sphere": True, "cylinder": False, "obj": True}),
                                               ("instance", {"sphere": False, "cylinder": False, "obj": False}),
                                               ("both", {"sphere": True, "cylinder": False, "obj": True})])
def test_mirrors_turn_shapes_inside_out_where_mitsuba_s_do(tmp_path, kind, where, inside_out):
    """Mitsuba 3.9 (renders of each case, one-sided shapes lit from above): a shape's own mirroring to_world turns
    a mesh and a sphere inside out, not a cylinder; an instance's mirror turns nothing inside out. probvis turned
    mirrored instances and cylinders inside out (a mirrored cylinder emitter lit 4x too little). Geometric and
    shading normals agree in every case."""
    (tmp_path / "q.obj").write_text("v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nf 1 2 3\nf 1 3 4\n")
    own = "<transform name='to_world'><scale y='-1'/></transform>" if where in ("own", "both") else ""
    shape = {"sphere": f"<shape type='sphere'>{own}</shape>",
             "cylinder": f"<shape type='cylinder'><point name='p0' y='-1'/><point name='p1' y='1'/>{own}</shape>",
             "obj": f"<shape type='obj'><string name='filename' value='q.obj'/>{own}</shape>"}[kind]
    if where == "own":
        body = shape
    else:
        body = (f"<shape type='shapegroup' id='g'>{shape}</shape><shape type='instance'><ref id='g'/>{MIRROR}"
                "</shape>")
    light = "<emitter type='point'><point name='position' z='5'/></emitter>"
    s = probvis.load_scene(write_scene(tmp_path / "s.xml", sensor() + light + body))
    t, vn = s.triangles, s.vertex_normals
    geometric = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    assert np.all(np.einsum("ij,ij->i", geometric, vn.mean(axis=1)) > 0)
    centre = t.reshape(-1, 3).mean(axis=0)
    out = t.mean(axis=1) - centre
    if kind == "cylinder":
        out[:, 1] = 0.0
    elif kind == "obj":
        out = np.array([0.0, 0.0, 1.0])
    facing = np.einsum("ij,ij->i", vn.mean(axis=1), out * np.ones_like(geometric))
    assert np.all(facing < 0) if inside_out[kind] else np.all(facing > 0)


@pytest.mark.parametrize("flip", ["", "<boolean name='flip_normals' value='true'/>"])
def test_a_mirrored_cylinder_emitter_warns_that_mitsuba_renders_it_otherwise(tmp_path, flip):
    """Mitsuba 3.9 splits a mirrored cylinder emitter's light between its sides (0.165 and 0.038 against 0.203
    unmirrored); probvis emits it as the unmirrored one (docs/decisions.md), and says so at its line. An unmirrored
    cylinder emitter says nothing."""
    cylinder = ("<shape type='cylinder'><point name='p0' y='-1'/><point name='p1' y='1'/>{}{}<emitter type='area'>"
                "<rgb name='radiance' value='1'/></emitter></shape>")
    path = write_scene(tmp_path / "s.xml", sensor() + cylinder.format(
        "<transform name='to_world'><scale y='-1'/></transform>", flip))
    line = next(i for i, text in enumerate(path.read_text().splitlines(), 1) if "type='cylinder'" in text)
    with pytest.warns(UserWarning, match=f"s.xml:{line}: a cylinder emitter under a mirroring to_world emits here "
                                         "as the unmirrored one; Mitsuba 3 splits its light"):
        probvis.load_scene(path)
    with warnings.catch_warnings(action="error"):
        probvis.load_scene(write_scene(tmp_path / "plain.xml", sensor() + cylinder.format("", flip)))


def test_a_negative_sphere_radius_turns_it_inside_out_as_in_mitsuba(tmp_path):
    """Mitsuba flips a sphere's normals for a negative radius (its render of a one-sided sphere of radius -0.4 lit
    from above: 0.0456, against 0.0532 for 0.4); probvis refused it."""
    light = "<emitter type='point'><point name='position' z='5'/></emitter>"
    body = sensor() + light + "<shape type='sphere'><float name='radius' value='-0.4'/></shape>"
    s = probvis.load_scene(write_scene(tmp_path / "s.xml", body))
    t = s.triangles
    assert np.allclose(np.linalg.norm(t, axis=2), 0.4)
    geometric = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    assert np.all(np.einsum("ij,ij->i", geometric, t.mean(axis=1)) < 0)
    assert np.all(np.einsum("ij,ij->i", s.vertex_normals.mean(axis=1), t.mean(axis=1)) < 0)


@pytest.mark.parametrize("origin, target, mitsuba", [  # Mitsuba 3.9.1's sensor world_transform of each
    ("0,0,4", "0,0,0", [[0, 1, 0, 0], [1, 0, 0, 0], [0, 0, -1, 4]]),
    ("0,1.5,0", "0,-1,0", [[0, 1, 0, 0], [0, 0, -1, 1.5], [-1, 0, 0, 0]]),
    ("1,2,3", "0,0,0", [[-0.0793, 0.9604, -0.2673, 1], [0.8414, -0.0793, -0.5345, 2], [-0.5345, -0.2673, -0.8018, 3]]),
])
@pytest.mark.parametrize("up", ["", ' up="0, 0, 0"'])
def test_a_lookat_without_up_is_turned_as_mitsuba_turns_it(tmp_path, origin, target, mitsuba, up):
    """Without `up` (or with a zero one), Mitsuba's parser takes the first vector of the view direction's
    coordinate system; probvis took +y: another roll of the camera, and a light looking straight down was refused
    as parallel to +y (a zero `up` was refused)."""
    body = sensor().replace('<lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/>',
                            f'<lookat origin="{origin}" target="{target}"{up}/>')
    assert f'target="{target}"{up}/>' in body
    spot = (f"<emitter type='spot'><transform name='to_world'><lookat origin='{origin}' target='{target}'/>"
            "</transform></emitter><shape type='rectangle'/>")
    scene = probvis.load_scene(write_scene(tmp_path / "s.xml", body + spot))
    np.testing.assert_allclose(scene.camera.to_world[:3], mitsuba, atol=1e-4)
    if importlib.util.find_spec("mitsuba") is not None:
        import mitsuba as mi

        mi.set_variant("scalar_rgb")
        theirs = mi.load_file(str(tmp_path / "s.xml")).sensors()[0].world_transform().matrix
        np.testing.assert_allclose(scene.camera.to_world, np.array(theirs), atol=1e-6)


@pytest.mark.parametrize("old, new, warned", [
    ('<float name="fov"', '<float name="shutter_open" value="0.2"/><float name="shutter_close" value="0.7"/>'
                          '<float name="fov"', None),
    ('<rgb name="radiance" value="1"/>', '<rgb name="radiance" value="1"/><float name="sampling_weight" value="3"/>',
     "sampling_weight ignored: probvis samples emitters by their power"),
    ('<shape type="cube"/>', '<shape type="cube"><boolean name="face_normals" value="true"/></shape>', None),
    ('</sensor>', '</sensor><sensor type="perspective"><float name="fov" value="90"/></sensor>',
     "a second <sensor>: probvis renders the first, as Mitsuba does"),
])
def test_what_mitsuba_accepts_and_does_not_change_the_image_is_accepted(tmp_path, old, new, warned):
    """A sensor's shutter times (a static scene), an emitter's sampling weight (the noise, not the expectation), a
    cube's face_normals (its faces are flat) and a second sensor (Mitsuba renders the first) were refused."""
    body = sensor() + LIGHT + '<shape type="cube"/>'
    assert old in body
    plain = probvis.render(write_scene(tmp_path / "a.xml", body), spp=2).image
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        changed = probvis.render(write_scene(tmp_path / "b.xml", body.replace(old, new, 1)), spp=2).image
    said = [str(w.message) for w in caught if "rendered" not in str(w.message)]
    assert (len(said) == 1 and warned in said[0]) if warned else not said
    assert np.array_equal(plain, changed)


def test_sampling_weights_on_many_emitters_are_said_once(tmp_path):
    """400 lights with a sampling_weight gave 400 identical lines."""
    lights = "".join(f"<shape type='sphere'><point name='center' value='{x}, 0, 2'/><float name='radius' "
                     "value='0.01'/><emitter type='area'><float name='sampling_weight' value='2'/></emitter></shape>"
                     for x in np.linspace(-1, 1, 400))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        probvis.load_scene(write_scene(tmp_path / "s.xml", sensor() + lights))
    said = [str(w.message) for w in caught if "sampling_weight" in str(w.message)]
    assert len(said) == 1 and "sampling_weight ignored (and on 399 more emitters)" in said[0], said[:3]


@pytest.mark.parametrize("body, message", [
    ("<shape type='rectangle'><emitter type='area'><texture type='bitmap' name='radiance'><string name='filename' "
     "value='x.png'/></texture></emitter></shape>", "<texture>: an emitter's radiance given as a texture is not "
                                                    "supported by probvis: give an <rgb> or <spectrum>"),
    ("<emitter type='point'><float name='sampling_weight' value='-1'/></emitter>",
     "<float>: sampling_weight must be above 0 and at most 1e+30, got -1"),
    ("<emitter type='constant'><float name='sampling_weight' value='-1'/></emitter>",  # 0 is allowed there
     "<float>: sampling_weight must be from 0 to 1e+30, got -1"),
    ("<emitter type='point'><float name='sampling_weight' value='0'/></emitter>",
     "got 0 (at 0 Mitsuba never samples this light, which only emitter sampling reaches: remove it, or give a "
     "positive weight)"),
    ("<emitter type='directional'><float name='sampling_weight' value='0'/></emitter>", "got 0 (at 0 Mitsuba never"),
    ("<emitter type='point'><float name='sampling_weight' value='1e-50'/></emitter>",  # Mitsuba: no probability mass
     "got 1e-50 (0 in Mitsuba's single precision) (at 0 Mitsuba never samples this light"),
])
def test_emitter_parameters_probvis_does_not_take_are_named(tmp_path, body, message):
    with pytest.raises(ProbvisError, match=re.escape(message)):
        probvis.load_scene(write_scene(tmp_path / "s.xml", sensor() + LIGHT + body))


@pytest.mark.parametrize("emitter, samples, warned", [
    ("<emitter type='point'><point name='position' x='0' y='0' z='3'/></emitter>", 2, True),
    ("<emitter type='directional'><vector name='direction' x='0' y='0' z='-1'/></emitter>", 4, True),
    ("<emitter type='point'><point name='position' x='0' y='0' z='3'/></emitter>", 1, False),
    ("", 4, False),  # the area light alone: Mitsuba weighs its samples right
    ("<emitter type='constant'/>", 4, False),  # an environment is no delta light
])
def test_delta_lights_with_several_emitter_samples_say_mitsuba_differs(tmp_path, emitter, samples, warned):
    """Mitsuba 3.9 renders point, spot and directional lights N times too bright at emitter_samples N (a
    documented difference); a user comparing the two saw a factor of N unexplained."""
    path = write_scene(tmp_path / "s.xml", sensor(sr=samples) + LIGHT + emitter)
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        probvis.load_scene(path)
    found = [str(w.message) for w in said if "times too bright" in str(w.message)]
    assert found == ([f"{path}:12: emitter_samples {samples} with point, spot or directional lights: Mitsuba 3.9 "
                      f"renders those lights {samples} times too bright (its delta lights' samples lack the 1/N); "
                      "probvis renders their true light, Mitsuba's image at emitter_samples 1"] if warned else [])


@pytest.mark.filterwarnings("ignore:.*bsdf_samples ignored")
@pytest.mark.parametrize("bsdf_samples, said", [
    (1, "sampling_weight 0 ignored: Mitsuba finds this emitter by BSDF sampling alone; probvis samples emitters by "
        "their power (the same expected image)"),
    (0, "sampling_weight 0 with bsdf_samples 0: Mitsuba never samples this emitter and its image lacks the "
        "emitter's light on the scene"),
])
def test_an_area_light_of_sampling_weight_0_is_rendered_as_mitsuba_s_bsdf_samples_find_it(tmp_path, bsdf_samples,
                                                                                           said):
    """Mitsuba never picks it by emitter sampling but finds it by BSDF sampling, so its light is in the image
    (probvis refused it with "remove it", which would have changed the image); with bsdf_samples 0 nothing finds
    it, and the warning says so without a hedge. With no emitter of a positive weight Mitsuba cannot load the
    scene ("DiscreteDistribution: no probability mass found"), and probvis refuses it at the weight's line."""
    light = LIGHT.replace("</emitter>", "<float name='sampling_weight' value='0'/></emitter>", 1)
    assert light != LIGHT
    other = "<emitter type='point'><point name='position' x='0' y='0' z='3'/></emitter>"
    camera = sensor(sr=1).replace("'bsdf_samples' value='0'", f"'bsdf_samples' value='{bsdf_samples}'")
    camera = camera.replace('"bsdf_samples" value="0"', f'"bsdf_samples" value="{bsdf_samples}"')
    path = write_scene(tmp_path / "s.xml", camera + light + other)
    with pytest.warns(UserWarning, match=re.escape(f"{path}:14: {said}")):
        scene = probvis.load_scene(path)
    assert scene.n_emitters == 2
    tiny = light.replace("value='0'/>", "value='1e-46'/>")  # 0 in Mitsuba's single precision
    alone = write_scene(tmp_path / "alone.xml", camera + light + tiny.replace("translate z", "translate x='1' z"))
    with pytest.raises(ProbvisError, match=re.escape("alone.xml:14: <float>: every emitter has sampling_weight 0: "
                                                     "Mitsuba 3 cannot load such a scene")):
        probvis.load_scene(alone)
    negative = write_scene(tmp_path / "neg.xml", camera + light.replace("value='0'/>", "value='-1e-50'/>") + other)
    with pytest.raises(ProbvisError) as err:  # negative, not 0: no word of what 0 would mean
        probvis.load_scene(negative)
    assert str(err.value).endswith("<float>: sampling_weight must be from 0 to 1e+30, got -1e-50")


def test_a_default_inside_an_element_declares_its_parameter_from_there_on(tmp_path):
    """Mitsuba's parser takes a <default> at any depth (its image of this file: mean 0.7491, probvis 0.7494 at 256
    spp); probvis refused it inside a shape. As in Mitsuba, a use above it is undefined."""
    nested = "<shape type='rectangle'><default name='r' value='0.5'/><bsdf type='diffuse'>" \
             "<rgb name='reflectance' value='$r'/></bsdf></shape>"
    sphere = "<shape type='sphere'><float name='radius' value='$r'/></shape>"
    scene = probvis.load_scene(write_scene(tmp_path / "s.xml", sensor() + LIGHT + nested + sphere))
    ball = scene.shapes[-1]
    assert np.allclose(ball.hi, 0.5, atol=0.01) and np.allclose(ball.lo, -0.5, atol=0.01)
    with pytest.raises(ProbvisError, match=re.escape("undefined parameter '$r'")):
        probvis.load_scene(write_scene(tmp_path / "t.xml", sensor() + LIGHT + sphere + nested))
    # inside an element a <ref> above it uses, which probvis reads at the <ref>: refused, not read out of order
    early = "<shape type='rectangle'><ref id='m'/></shape><default name='r' value='0.9'/><bsdf type='diffuse' id='m'>" \
            "<default name='r' value='0.5'/><rgb name='reflectance' value='$r'/></bsdf>"
    with pytest.raises(ProbvisError, match="a <default> inside an element that a <ref> above it uses"):
        probvis.load_scene(write_scene(tmp_path / "u.xml", sensor() + LIGHT + early))


def test_a_vertex_no_face_uses_may_lie_anywhere(tmp_path):
    """Mitsuba renders a mesh whose unused vertex lies at 1e31 (probvis refused it as beyond ±1e30): it counts
    neither in the limit nor in the shape's bounds; a used one beyond is still refused."""
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1e31 0 0\nf 1 2 3\n")
    shape = "<shape type='obj'><string name='filename' value='m.obj'/></shape>"
    scene = probvis.load_scene(write_scene(tmp_path / "s.xml", sensor() + LIGHT + shape))
    mesh = scene.shapes[-1]
    assert mesh.n_triangles == 1 and mesh.hi.tolist() == [1.0, 1.0, 0.0] and mesh.lo.tolist() == [0.0, 0.0, 0.0]
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1e31 0 0\nf 1 2 3\nf 1 2 4\n")
    with pytest.raises(ProbvisError, match="has vertices beyond ±1e\\+30 once transformed"):
        probvis.load_scene(tmp_path / "s.xml")


def test_a_negative_cylinder_radius_is_the_same_cylinder_as_in_mitsuba(tmp_path):
    """Mitsuba scales its cylinder's frame by the radius: a negative one turns it half a turn about its axis, the
    same surface facing out (its render lit by a point light: 0.04628 for 0.3 and -0.3); probvis refused it."""
    def cylinder(r):
        body = sensor() + LIGHT + f"<shape type='cylinder'><float name='radius' value='{r}'/></shape>"
        s = probvis.load_scene(write_scene(tmp_path / "c.xml", body))
        return s.triangles[s.shapes[1].first_triangle:]

    pos, neg = cylinder(0.3), cylinder(-0.3)
    corners = [np.sort(np.round(c.reshape(-1, 3), 9), axis=0) for c in (pos, neg)]
    assert np.allclose(*corners)
    t = neg
    out = t.mean(axis=1) * np.array([1.0, 1.0, 0.0])
    assert np.all(np.einsum("ij,ij->i", np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), out) > 0)


def test_obj_mesh_relative_path_and_twosided(tmp_path):
    (tmp_path / "m").mkdir()
    (tmp_path / "m" / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 3\nf 1 1 2\n")
    body = sensor() + LIGHT + """<shape type="obj"><string name="filename" value="m/tri.obj"/>
        <bsdf type="twosided"><bsdf type="diffuse"/></bsdf></shape>"""
    s = probvis.load_scene(write_scene(tmp_path / "s.xml", body))
    assert s.shapes[1].n_triangles == 2 and s.dropped_degenerate == 1
    assert s.twosided[s.tri_material[-1]]


def test_obj_materials_and_groups_are_ignored_as_by_mitsuba(tmp_path):
    """An OBJ's usemtl, mtllib, g and o lines do not split the mesh: faces stay in file order, uv are the
    file's (flipped in v, as Mitsuba's default), and the .mtl it names need not exist."""
    from probvis.scene.shapes import load_mesh

    (tmp_path / "m.obj").write_text(
        "mtllib missing.mtl\no thing\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\n"
        "vt 0 0\nvt 1 0\nvt 0 1\nvt 1 1\ng a\nusemtl red\nf 1/1 2/2 4/4\nusemtl blue\nf 1/1 3/3 2/2\n"
        "usemtl red\nf 2/2 4/4 3/3\n")
    mesh = load_mesh(tmp_path / "m.obj")
    corners = np.array([[0, 0], [1, 0], [0, 1], [1, 1]], float)
    np.testing.assert_array_equal(mesh.vertices[mesh.faces][:, :, :2], corners[[[0, 1, 3], [0, 2, 1], [1, 3, 2]]])
    np.testing.assert_array_equal(mesh.uv[mesh.faces], (corners * [1, -1] + [0, 1])[[[0, 1, 3], [0, 2, 1],
                                                                                         [1, 3, 2]]])
    assert len(mesh.vertices) == 4


@pytest.mark.parametrize("body, message", [
    ("<shape type='rectangle'><emitter type='point'/></shape>", "unsupported emitter type 'point'"),
    ("<shape type='hyperboloid'/>", "unsupported shape type 'hyperboloid'"),
    ("<bsdf type='velvet' id='x'/>", "unsupported bsdf type 'velvet'"),
    ("<shape type='rectangle'><float name='radius' value='1'/></shape>", "unsupported parameter 'radius'"),
    ("<shape type='obj'><string name='filename' value='nope.obj'/></shape>", "mesh file not found"),
    ("<shape type='rectangle'><ref id='missing'/></shape>", "unknown id 'missing'"),
    ("<shape type='rectangle'><transform name='to_world'><shear/></transform></shape>", "unsupported transform"),
    ("<shape type='rectangle'><boolean name='flip_normals' value='$undefined'/></shape>",
     "undefined parameter '$undefined'"),
    ("<emitter type='skydome'/>", "unsupported emitter type 'skydome'"),
    ("<texture type='bitmap'/>", "a top-level texture needs an 'id'"),
    ("<medium type='homogeneous' id='fog'/>", "unsupported element"),
    ("<shape type='instance'><ref id='nothing'/></shape>", "reference to unknown id 'nothing'"),
    ("<shape type='serialized'><string name='filename' value='nope.serialized'/></shape>", "mesh file not found"),
    ("<emitter type='spot'><float name='cutoff_angle' value='120'/></emitter>",
     "cutoff_angle 120: a spot wider than a hemisphere"),
    ("<emitter type='point'><point name='position' x='abc'/></emitter>", "attribute 'x': 'abc' is not a number"),
    ("<emitter type='point'><point name='position' x='nan'/></emitter>", "non-finite value 'nan'"),
    ("<shape type='rectangle'><transform name='to_world'><rotate x='1' angle='inf'/></transform></shape>",
     "non-finite value 'inf'"),
    ("<texture type='checkerboard' id='c'><rgb name='color0' value='-5'/></texture>", "within [0, 1]"),
    ("<texture type='checkerboard' id='c'><rgb name='color1' value='1e30'/></texture>", "within [0, 1]"),
    ("<emitter type='point'><rgb name='intensity' value='1e200'/></emitter>", "intensity 1e+200 is out of range"),
    ("<emitter type='directional'><rgb name='irradiance' value='1e31'/></emitter>", "out of range"),
    ("<shape type='rectangle'><emitter type='area'><rgb name='radiance' value='2e30'/></emitter></shape>",
     "out of range"),
    ("<bsdf type='diffuse' id='a'/><bsdf type='diffuse' id='a'/>", "duplicate id 'a'"),
    ("<shape type='shapegroup' id='g'><shape type='instance'><ref id='g'/></shape></shape>", "nested instancing"),
    ("<shape type='shapegroup' id='g'><shape type='rectangle'><emitter type='area'><rgb name='radiance' value='1'/>"
     "</emitter></shape></shape>", "an emitter inside a shapegroup is not supported"),
    ("<shape type='rectangle'><boolean name='flip_normals' value='true'/><boolean name='flip_normals' value='false'/>"
     "</shape>", "parameter 'flip_normals' is given twice"),
    ("<shape type='cube' id='c'/><shape type='rectangle'><ref id='c'/></shape>", "id 'c' is a <shape>, not a bsdf"),
    ("<shape type='rectangle'><ref id='p'/></shape><bsdf type='twosided' id='p'><ref id='q'/></bsdf>"
     "<bsdf type='twosided' id='q'><ref id='p'/></bsdf>",
     "references that go round in a circle ('p' -> 'q' -> 'p')"),
    ("<shape type='instance'><ref id='g'/></shape><shape type='shapegroup' id='g'><shape type='cube'/></shape>",
     "id 'g' is defined after this reference (line"),
    ("<shape type='obj'><string name='filename' value='.'/></shape>", "is not a regular file"),
    ("<default name='res'/>", "missing attribute 'value' of parameter 'res'"),
    ("<shape type='rectangle'><emitter type='area'><spectrum name='radiance' value='5000:1, 6000:1'/></emitter>"
     "</shape>", "wavelengths 5000-6000 nm lie outside 360-830 nm"),
    ("<shape type='rectangle'><bsdf type='diffuse'><spectrum name='reflectance' value='0.4:0.5, 0.7:0.5'/></bsdf>"
     "</shape>", "wavelengths 0.4-0.7 nm lie outside 360-830 nm: this reflectance would be black"),
    ("<shape type='rectangle'><boolean name='flip_normals' value='$late'/></shape><default name='late' value='1'/>",
     "parameter '$late' is declared on line"),
    ("<default name='a' value='$a'/>", "parameter '$a' refers to itself"),
    ("<default name='a' value='$b'/><default name='b' value='1'/>", "parameter '$b' is declared on line"),
    ("<default name='n' value='2'/><shape type='sphere'><float name='radius' value='$$n'/></shape>",
     "'$$n' has a '$' that starts no parameter's name"),
    ("<shape type='sphere'><float name='radius' value='4$'/></shape>", "'4$' has a '$' that starts no parameter's"),
    ("<default name='' value='3'/>", "a <default> needs a parameter name (it is empty)"),
    ("<shape type='rectangle'><bsdf type='diffuse'><rgb name='reflectance' value='0.5'/>\n"
     "<texture type='checkerboard' name='reflectance'/></bsdf></shape>", "parameter 'reflectance' is given twice"),
    ("<shape type='rectangle'><bsdf type='diffuse'><texture type='checkerboard'/>\n<texture type='checkerboard'/>"
     "</bsdf></shape>", "parameter 'reflectance' is given twice"),
    ("<shape type='rectangle'><bsdf type='plastic'><rgb name='diffuse_reflectance' value='0.5'/>\n"
     "<rgb name='diffuse_reflectance' value='0.1'/></bsdf></shape>", "parameter 'diffuse_reflectance' is given twice"),
    ("<shape type='rectangle'><bsdf type='dielectric'><float name='int_ior' value='1.5'/>\n"
     "<string name='int_ior' value='diamond'/></bsdf></shape>", "parameter 'int_ior' is given twice"),
    ("<integrator type='path'><integer name='max_depth' value='1'/></integrator>",
     "max_depth 1 renders no direct illumination in Mitsuba"),
    ("<shape type='rectangle'><transform name='to_world'><matrix value='1 0 0 0 1 0 0 0 0 0 0 0 0 0 0 1'/>"
     "</transform><emitter type='area'><rgb name='radiance' value='1'/></emitter></shape>",
     "the shape's to_world is singular or projective"),
])
def test_unsupported_input_names_file_line_and_element(tmp_path, body, message):
    head = sensor() if "<integrator" not in body else re.sub(r"<integrator.*?</integrator>", "", sensor(), flags=re.S)
    path = write_scene(tmp_path / "bad.xml", head + LIGHT + "\n" + body)
    with pytest.raises(ProbvisError) as exc:
        probvis.load_scene(path)
    text = str(exc.value)
    assert message in text
    assert f"{path}:" in text
    line = int(text.split(f"{path}:")[1].split(":")[0])
    assert body.split()[0].strip("<") in path.read_text().splitlines()[line - 1]


@pytest.mark.parametrize("kind, params, message", [
    ("perspective", "<float name='principal_point_offset_x' value='1e10'/>",
     "principal_point_offset (1e+10, 0) moves the image more than 1000 film sizes off its axis"),
    ("thinlens", "<float name='aperture_radius' value='1e20'/><float name='focus_distance' value='4'/>",
     "aperture_radius 1e+20 is more than 1000 times the focus_distance 4"),
])
def test_a_sensor_whose_rays_miss_its_view_is_named_at_its_line(tmp_path, kind, params, message):
    body = sensor().replace('<sensor type="perspective">', f'<sensor type="{kind}">{params}')
    path = write_scene(tmp_path / "bad.xml", body + LIGHT)
    with pytest.raises(ProbvisError, match=re.escape(str(path)) + r":\d+: <sensor>: " + re.escape(message)):
        probvis.load_scene(path)
    path = write_scene(tmp_path / "good.xml", body.replace("1e10", "0.5").replace("1e20", "0.1") + LIGHT)
    probvis.load_scene(path)


def test_malformed_xml_reports_the_line(tmp_path):
    path = tmp_path / "bad.xml"
    path.write_text('<scene version="3.0.0">\n<shape type="rectangle">\n</scene>\n')
    with pytest.raises(ProbvisError, match=r"bad.xml:3: malformed XML"):
        probvis.load_scene(path)


def test_missing_file_no_emitter_nan_vertices(tmp_path):
    with pytest.raises(ProbvisError, match="scene file not found"):
        probvis.load_scene(tmp_path / "nope.xml")
    with pytest.raises(ProbvisError, match="no emitter"):
        probvis.load_scene(write_scene(tmp_path / "dark.xml", sensor() + "<shape type='cube'/>"))
    with pytest.raises(ProbvisError, match=r"contains no \(non-degenerate\) triangles \(an environment alone is a "
                                           "background with nothing for it to light"):
        probvis.load_scene(write_scene(tmp_path / "sky.xml", sensor() + "<emitter type='constant'/>"))
    with pytest.raises(ProbvisError, match=r"scene 'empty' contains no \(non-degenerate\) triangles: nothing to "
                                           r"light, the image would be black \(as Mitsuba renders it\): add a shape"):
        probvis.load_scene(write_scene(tmp_path / "empty.xml", sensor()))
    (tmp_path / "nan.obj").write_text("v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n")
    body = sensor() + LIGHT + "<shape type='obj'><string name='filename' value='nan.obj'/></shape>"
    with pytest.raises(ProbvisError, match="nan.obj:2: mesh nan.obj has NaN or infinite vertex coordinates"):
        probvis.load_scene(write_scene(tmp_path / "nan.xml", body))
    # unused, beside faces with normals (which the reader numbers anew): Mitsuba's OBJ reader refuses it too
    (tmp_path / "nan.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv inf 0 0\nvn 0 0 1\nf 1//1 2//1 3//1\n")
    with pytest.raises(ProbvisError, match="nan.obj:4: mesh nan.obj has NaN or infinite vertex coordinates"):
        probvis.load_scene(tmp_path / "nan.xml")


@pytest.mark.parametrize("w, h", [(0, 16), (16, -3), (100000, 16)])
def test_silly_resolution(tmp_path, w, h):
    with pytest.raises(ProbvisError, match="out of range"):
        probvis.load_scene(write_scene(tmp_path / "s.xml", sensor(w=w, h=h) + LIGHT))


def test_builtin_scenes_are_generated_valid_and_render():
    for name in probvis.BUILTINS:
        s = probvis.load_scene(name, res=8, spp=1)
        assert s.n_triangles > 0 and s.n_emitters >= 1 and s.camera.width == 8
        assert np.all(np.isfinite(s.triangles))
        image = probvis.render(s, shadow_rays=1).image
        assert np.all(np.isfinite(image)) and image.mean() > 0
    with pytest.raises(ProbvisError, match="no parameter 'fov'"):
        probvis.load_scene("cornell-box", fov=3)


def test_shared_scenes_load(shared):
    for name, tris in (("cornell-bunny", 69463), ("city", 30074), ("leaves", 4004)):
        s = probvis.load_scene(shared / "scenes" / f"{name}.xml", res=32)
        assert s.n_triangles + s.dropped_degenerate == tris
        assert s.camera.width == 32 and s.defaults.spp == 16 and s.defaults.shadow_rays == 16


@pytest.mark.parametrize("params, message", [
    ('<string name="focal_length" value="fiftymm"/>', "focal_length must be of the form <x>mm"),
    ('<string name="focal_length" value="-5mm"/>', "focal_length must be positive"),
    ('<float name="fov" value="40"/><string name="focal_length" value="50mm"/>', "give either 'fov' or 'focal_length'"),
])
def test_bad_camera_parameters_name_file_and_line(tmp_path, params, message):
    body = f"""<sensor type="perspective">{params}<film type="hdrfilm"><integer name="width" value="8"/>
        <integer name="height" value="8"/><rfilter type="box"/></film></sensor>""" + LIGHT
    path = write_scene(tmp_path / "cam.xml", body)
    with pytest.raises(ProbvisError, match=rf"cam.xml:\d+: <sensor>: {message}"):
        probvis.load_scene(path)


def test_singular_sensor_transforms_are_refused(tmp_path):
    for op in ('<scale value="0"/>', '<scale x="1" y="0" z="1"/>',
               '<matrix value="1 0 0 0  0 1 0 0  0 0 1 0  0 0 1 1"/>'):
        body = sensor() + LIGHT
        body = body.replace('<transform name="to_world">', f'<transform name="to_world">{op}', 1)
        with pytest.raises(ProbvisError, match="to_world is singular or projective"):
            probvis.load_scene(write_scene(tmp_path / "s.xml", body))


def test_deep_nesting_and_non_files_are_refused(tmp_path):
    body = sensor() + LIGHT + "<bsdf type='mask' id='m'>" * 100 + "<bsdf type='diffuse'/>" + "</bsdf>" * 100
    with pytest.raises(ProbvisError, match=r"s.xml:\d+: <bsdf>: elements nested more than 64 deep"):
        probvis.load_scene(write_scene(tmp_path / "s.xml", body))
    with pytest.raises(ProbvisError, match="not a regular file"):
        probvis.load_scene(tmp_path)
    (tmp_path / "e.xml").write_text("")
    with pytest.raises(ProbvisError, match="e.xml:1: malformed XML"):
        probvis.load_scene(tmp_path / "e.xml")


def test_truncated_ply_empty_texture_and_a_plain_direct_integrator(tmp_path):
    (tmp_path / "t.ply").write_text("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
                                    "property float z\nelement face 2\nproperty list uchar int vertex_indices\n"
                                    "end_header\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n3 0 1 2\n")
    body = sensor() + LIGHT + '<shape type="ply"><string name="filename" value="t.ply"/></shape>'
    with pytest.raises(ProbvisError, match="truncated or malformed PLY .*declares 4 vertices and 2 faces"):
        probvis.load_scene(write_scene(tmp_path / "s.xml", body))
    (tmp_path / "empty.png").write_bytes(b"")
    body = sensor() + LIGHT + """<shape type="rectangle"><bsdf type="diffuse"><texture type="bitmap"
        name="reflectance"><string name="filename" value="empty.png"/></texture></bsdf></shape>"""
    with pytest.raises(ProbvisError, match=r"empty.png is empty \(0 bytes\)"):
        probvis.load_scene(write_scene(tmp_path / "s.xml", body))
    plain = sensor().replace(
        '<integrator type="direct"><integer name="emitter_samples" value="4"/><integer name="bsdf_samples" '
        'value="0"/></integrator>', '<integrator type="direct"/>')
    assert '<integrator type="direct"/>' in plain
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        probvis.load_scene(write_scene(tmp_path / "s.xml", plain + LIGHT))


@pytest.mark.parametrize("old, new, message", [
    ('<rfilter type="box"/>', '<rfilter type="tent"><float name="radius" value="0.001"/></rfilter>',
     "tent radius 0.001 reaches 0.001 pixels: only 4e-06 of the camera samples would reach a pixel centre"),
    ('<rfilter type="box"/>', '<rfilter type="gaussian"><float name="stddev" value="1e-5"/></rfilter>',
     "gaussian stddev 1e-05 reaches 4e-05 pixels"),
    ('<transform name="to_world">', '<transform name="to_world"><scale value="1e-12"/>',
     "the camera's to_world scales or shears (M M^T differs from the identity by 1)"),
    ('<transform name="to_world">', '<transform name="to_world"><scale x="2"/>',
     "the camera's to_world scales or shears (M M^T differs from the identity by 3): a camera takes only a rotation"),
    ('<transform name="to_world">', '<transform name="to_world"><matrix value="1 0.1 0 0 0 1 0 0 0 0 1 0 0 0 0 1"/>',
     "the camera's to_world scales or shears (M M^T differs from the identity by 0.1"),
    ('<rfilter type="box"/>', '<rfilter type="box"/><boolean name="sample_border" value="true"/>',
     "<boolean>: sample_border is not supported: probvis samples the image's own pixels only"),
    ('<float name="fov" value="40"/>', '<float name="fov" value="40"/><float name="fov" value="90"/>',
     "parameter 'fov' is given twice"),
])
def test_sensor_values_that_would_render_black_are_refused(tmp_path, old, new, message):
    path = write_scene(tmp_path / "bad.xml", sensor().replace(old, new) + LIGHT)
    with pytest.raises(ProbvisError, match=re.escape(message)):
        probvis.load_scene(path)


def test_entity_declarations_are_refused_with_their_line(tmp_path):
    path = tmp_path / "bomb.xml"
    path.write_text('<?xml version="1.0"?>\n<!DOCTYPE scene [<!ENTITY lol "lol">]>\n<scene version="3.0.0">'
                    '&lol;</scene>\n')
    with pytest.raises(ProbvisError, match=re.escape(f"{path}:2: an entity declaration (<!ENTITY>) is not allowed")):
        probvis.load_scene(path)


@pytest.mark.parametrize("faces, message", [
    ("f 0 1 2", "m.obj:5: face index 0 is invalid (OBJ indices start at 1)"),
    ("f 1 2", "m.obj:5: a face needs at least 3 vertices"),
    ("f 1//1 2//9 3//1", "m.obj:5: face refers to normal 9, but the file defines only 1 normals"),
    ("f 1/5 2/1 3/1", "m.obj:5: face refers to texture coordinate 5, but the file defines only 1 texture coordinates"),
    ("f -1 -2 -4", "m.obj:5: face refers to vertex -4, but only 3 vertices are defined before it"),
])
def test_obj_faces_a_reader_would_misread_are_named_with_their_line(tmp_path, faces, message):
    from probvis.scene.shapes import load_mesh

    (tmp_path / "m.obj").write_text(f"v 0 0 1\nv 1 0 1\nv 0 1 1\nvn 0 0 1\n{faces}\nvt 0 0\n"
                                    if "/5" not in faces else f"v 0 0 1\nv 1 0 1\nv 0 1 1\nvt 0 0\n{faces}\n")
    with pytest.raises(ProbvisError, match=re.escape(message)):
        load_mesh(tmp_path / "m.obj")


def test_a_default_declared_twice_keeps_the_first_as_mitsuba_does(tmp_path):
    path = write_scene(tmp_path / "twice.xml", sensor(w="$res", h="$res") + LIGHT,
                       defaults='<default name="res" value="8"/>\n<default name="res" value="4"/>')
    with pytest.warns(UserWarning, match="<default> of 'res' declared again"):
        scene = probvis.load_scene(path)
    assert scene.camera.width == 8



@pytest.mark.parametrize("body, message", [
    ("<emitter type='point'><point name='position' x='0' y='0' z='1e300'/></emitter>",
     "<emitter>: the light's position 0, 0, 1e+300 is beyond ±1e+30"),
    ("<emitter type='spot'><transform name='to_world'><scale value='0'/></transform></emitter>",
     "<emitter>: the spot light's to_world is singular"),
    ("<shape type='rectangle'><bsdf type='dielectric'><float name='int_ior' value='-1.5'/></bsdf></shape>",
     "<float>: int_ior of a dielectric bsdf must be positive, got -1.5"),
    ("<shape type='rectangle'><bsdf type='diffuse'><texture type='checkerboard' name='reflectance'><texture "
     "type='checkerboard' name='color0'/></texture></bsdf></shape>",
     "<texture>: a checkerboard's 'color0' is a texture: probvis reads a checkerboard's colours as <rgb>"),
    ("<shape type='rectangle'><bsdf type='plastic'><float name='int_ior' value='-1'/></bsdf></shape>",
     "<float>: int_ior of a plastic bsdf must be positive, got -1"),
    ("<shape type='rectangle'><bsdf type='roughplastic'><float name='ext_ior' value='0'/></bsdf></shape>",
     "<float>: ext_ior of a roughplastic bsdf must be positive, got 0"),
    ("<shape type='rectangle'><bsdf type='roughdielectric'><float name='int_ior' value='1.5'/><float name='ext_ior' "
     "value='1.50000001'/></bsdf></shape>", "<bsdf>: int_ior and ext_ior of a roughdielectric bsdf must differ "
                                            "(Mitsuba refuses equal ones"),
    ("<shape type='rectangle'><bsdf type='roughplastic'><float name='ext_ior' value='1.49'/></bsdf></shape>",
     "<bsdf>: int_ior and ext_ior of a roughplastic bsdf must differ (Mitsuba refuses equal ones"),
    ("<shape type='rectangle'><bsdf type='roughplastic'><string name='int_ior' value='kryptonite'/></bsdf></shape>",
     "<string>: unknown material 'kryptonite' for int_ior"),
    ("<shape type='rectangle'><bsdf type='principled'><float name='eta' value='-1'/></bsdf></shape>",
     "<float>: eta of a principled bsdf must be positive (Mitsuba renders it as NaN), got -1"),
    ("<shape type='rectangle'><bsdf type='roughplastic'><rgb name='diffuse_reflectance' value='0.2, 0.9, 1.7'/>"
     "</bsdf></shape>", "<rgb>: 'diffuse_reflectance' of a roughplastic bsdf is a reflectance: an <rgb> must be "
                        "within [0, 1], got 0.2, 0.9, 1.7"),
    ("<shape type='rectangle'><bsdf type='principled'><rgb name='base_color' value='2'/></bsdf></shape>",
     "<rgb>: 'base_color' of a principled bsdf is a reflectance"),
    ("<shape type='rectangle'><bsdf type='conductor'><rgb name='specular_reflectance' value='2'/></bsdf></shape>",
     "<rgb>: 'specular_reflectance' of a conductor bsdf is a reflectance"),
    ("<shape type='rectangle'><bsdf type='plastic'><rgb name='specular_reflectance' value='-0.1'/></bsdf></shape>",
     "<rgb>: 'specular_reflectance' of a plastic bsdf is a reflectance"),
    ("<shape type='rectangle'><bsdf type='diffuse'><spectrum name='reflectance' value='400:5, 700:5'/></bsdf>"
     "</shape>", "<spectrum>: reflectance must be within [0, 1] at every wavelength"),
    ("<shape type='rectangle'><bsdf type='plastic'><spectrum name='diffuse_reflectance' value='0.9, 0.1, 0.1'/>"
     "</bsdf></shape>", "<spectrum>: a spectrum is one value or wavelength:value pairs"),  # was grey 0.5, silent
    ("<shape type='rectangle'><bsdf type='plastic'><spectrum name='diffuse_reflectance' value='0.9 0.1'/>"
     "</bsdf></shape>", "<spectrum>: a spectrum is one value or wavelength:value pairs, got '0.9 0.1'"),
    ("<shape type='rectangle'><bsdf type='conductor'><spectrum name='specular_reflectance' value='abc def'/>"
     "</bsdf></shape>", "<spectrum>: "),
    ("<shape type='rectangle'><bsdf type='diffuse'><texture type='checkerboard' name='reflectance'>"
     "<transform name='to_uv'><scale value='1e20'/></transform></texture></bsdf></shape>",
     "<texture>: to_uv has entries beyond ±1e+09"),
    ("<shape type='rectangle'><transform name='to_world'><translate z='1e39'/></transform></shape>",
     "has vertices beyond ±1e+30 once transformed"),
    ("<integrator type='direct'/><integrator type='direct'/>", "<integrator>: only one integrator per scene"),
    ("<shape type='rectangle'><bsdf type='diffuse'><texture type='noise' name='reflectance'/></bsdf></shape>",
     "<texture>: unsupported texture type 'noise'"),
    ("<emitter type='spot'><transform name='to_world'><lookat origin='0, 0, 1e300' target='0, 0, 0'/></transform>"
     "</emitter>", "<lookat>: lookat's origin and target must lie within ±1e+30"),
    ("<shape type='sphere'><float name='radius' value='1e100'/></shape>",
     "<shape>: sphere radius must be at most 1e+30 in size, got 1e+100"),
    ("<shape type='rectangle'><bsdf type='dielectric'><string name='int_ior' value='kryptonite'/></bsdf></shape>",
     "<string>: unknown material 'kryptonite' for int_ior (Mitsuba's: vacuum, helium"),
    ("<shape type='rectangle'><bsdf type='roughconductor'><string name='material' value='unobtainium'/></bsdf>"
     "</shape>", "<bsdf>: unknown conductor material 'unobtainium' (Mitsuba's: Ag, Al,"),
    ("<shape type='rectangle'><bsdf type='dielectric'><rgb name='int_ior' value='1.5'/></bsdf></shape>",
     "<rgb>: 'int_ior' of a dielectric bsdf is given as <float> or <string>"),
    ("<shape type='rectangle'><bsdf type='plastic'><string name='diffuse_reflectance' value='red'/></bsdf></shape>",
     "<string>: 'diffuse_reflectance' of a plastic bsdf is given as <rgb> or <spectrum> or <float> or a <texture>"),
    ("<shape type='rectangle'><bsdf type='conductor'><rgb name='material' value='0.5'/></bsdf></shape>",
     "<rgb>: 'material' of a conductor bsdf is given as <string>"),
    ("<shape type='rectangle'><bsdf type='principled'><boolean name='base_color' value='true'/></bsdf></shape>",
     "<boolean>: 'base_color' of a principled bsdf is given as <rgb>"),
    ("<shape type='rectangle'><bsdf type='blendbsdf'><string name='weight' value='half'/><bsdf type='diffuse'/>"
     "<bsdf type='diffuse'/></bsdf></shape>", "<string>: 'weight' of a blendbsdf bsdf is given as <rgb>"),
    ("<shape type='rectangle'><bsdf type='diffuse'><spectrum name='reflectance' value='nan:0.5, 500:0.5'/></bsdf>"
     "</shape>", "<spectrum>: non-finite wavelength or value in 'nan:0.5, 500:0.5'"),
    ("<shape type='rectangle'><bsdf type='diffuse'><spectrum name='reflectance' value='4_00:0.5, 500:0.5'/>"
     "</bsdf></shape>", "<spectrum>: expected wavelength:value pairs, got '4_00:0.5, 500:0.5'"),
    ("<shape type='rectangle'><emitter type='area'><spectrum name='radiance' value='400:1e308, 500:1e308'/>"
     "</emitter></shape>", "<spectrum>: spectrum value 1e+308 is out of range (at most 1e+30)"),
    ("<emitter type='constant'><rgb name='radiance' value='1e-300'/></emitter>",
     "<emitter>: radiance 1e-300 is out of range (non-zero values must be at least 1e-30"),
    ("<shape type='cylinder'><point name='p1' x='0' y='0' z='1e-15'/></shape>",
     "<shape>: a cylinder of radius 1 from p0 to p1 1e-15 apart is too flat"),
    ("<shape type='cylinder'><point name='p1' x='0' y='1e200' z='0'/></shape>",  # 'inf apart: move them apart'
     "<shape>: a cylinder's p1 (0, 1e+200, 0) lies beyond ±1e+30: rescale the scene"),
    ("<shape type='rectangle'><bsdf type='plastic'><rgb name='diffuse_reflectance' value='-0.5'/></bsdf></shape>",
     "<rgb>: 'diffuse_reflectance' of a plastic bsdf is a reflectance: an <rgb> must be within [0, 1], got -0.5"),
    ("<shape type='rectangle'><bsdf type='blendbsdf'><float name='weight' value='2'/><bsdf type='diffuse'/>"
     "<bsdf type='diffuse'/></bsdf></shape>", "<float>: a blendbsdf's weight is between 0 and 1, got 2, 2, 2"),
    ("<emitter type='spot'><float name='cutoff_angle' value='1e-9'/></emitter>",
     "<emitter>: cutoff_angle must be in [0.001, 90] degrees, got 1e-09"),
    ("<shape type='rectangle'><transform name='to_world'><rotate x='1e300' y='1e300' angle='90'/></transform>"
     "</shape>", "<rotate>: the transform's entries go beyond ±1e+100 here"),
    ("<shape type='rectangle'><transform name='to_world'><scale value='1e200'/><scale value='1e200'/>"
     "</transform></shape>", "<scale>: the transform's entries go beyond ±1e+100 here"),
    ("<shape type='rectangle'><bsdf type='normalmap'><texture type='bitmap' name='normalmap'><string "
     "name='filename' value='nope.png'/></texture><bsdf type='diffuse'/></bsdf></shape>", "image not found"),
    ("<emitter type='point'><transform name='to_world'><matrix value='1 0 0 0 0 1 0 0 0 0 1 0 0 0 1 1'/>"
     "</transform></emitter>", "<emitter>: the light's to_world is projective (its last row must be 0 0 0 1)"),
])
def test_values_that_parse_but_would_render_nonsense_are_named_at_their_line(tmp_path, body, message):
    """Values Mitsuba would refuse, or that overflow probvis's arithmetic (NaN or black images before)."""
    path = write_scene(tmp_path / "bad.xml", sensor() + body + LIGHT)
    with pytest.raises(ProbvisError, match=re.escape(message)):
        probvis.load_scene(path)


@pytest.mark.parametrize("bsdf, message", [
    ("<bsdf type='plastic'><rgb name='diffuse_reflectence' value='1, 0, 0'/></bsdf>",
     "<rgb>: unsupported parameter 'diffuse_reflectence' for bsdf 'plastic' (its parameters: diffuse_reflectance,"),
    ("<bsdf type='roughplastic'><texture type='checkerboard' name='diffuse'/></bsdf>",
     "<texture>: unsupported parameter 'diffuse' for bsdf 'roughplastic'"),
    ("<bsdf type='plastic'><point name='diffuse_reflectance' x='1'/></bsdf>",
     "<point>: unsupported element <point> inside <bsdf type='plastic'>"),
    ("<bsdf type='plastic'><emitter type='area'><rgb name='radiance' value='1'/></emitter></bsdf>",
     "<emitter>: unsupported element <emitter> inside <bsdf type='plastic'>"),
    ("<bsdf type='blendbsdf'><bsdf type='diffuse'/></bsdf>", "<bsdf>: bsdf 'blendbsdf' nests exactly two bsdfs, got 1"),
    ("<bsdf type='blendbsdf'><bsdf type='diffuse'/><bsdf type='diffuse'/><bsdf type='diffuse'/></bsdf>",
     "bsdf 'blendbsdf' nests exactly two bsdfs, got 3"),
    ("<bsdf type='mask'><bsdf type='diffuse'/><bsdf type='diffuse'/></bsdf>",
     "bsdf 'mask' nests exactly one bsdf, got 2"),
    ("<bsdf type='conductor'><bsdf type='diffuse'/></bsdf>", "bsdf 'conductor' nests no other bsdf, got 1"),
    ("<bsdf type='twosided'><bsdf type='diffuse'/><bsdf type='diffuse'/><bsdf type='diffuse'/></bsdf>",
     "twosided takes one nested bsdf (both sides) or two (the front's, then the back's), got 3"),
    ("<bsdf type='roughconductor'><string name='distribution' value='bogus'/></bsdf>",
     "<string>: 'distribution' of a roughconductor bsdf is beckmann or ggx, got 'bogus'"),
    ("<bsdf type='conductor'><string name='material' value='Au'/><rgb name='eta' value='0.2'/></bsdf>",
     "a conductor bsdf takes either a material or eta and k, not both"),
    ("<bsdf type='roughconductor'><float name='alpha' value='0.1'/><float name='alpha_u' value='0.2'/></bsdf>",
     "a roughconductor bsdf takes either alpha or both alpha_u and alpha_v"),
    ("<bsdf type='plastic'><string name='nonlinear' value='maybe'/></bsdf>",
     "<string>: 'nonlinear' of a plastic bsdf is given as <boolean>"),
    ("<bsdf type='principled'><string name='roughness' value='rough'/></bsdf>",
     "'roughness' of a principled bsdf is given as <rgb> or <spectrum> or <float> or a <texture>"),
    ("<bsdf type='dielectric'><integer name='int_ior' value='2'/></bsdf>",
     "<integer>: 'int_ior' of a dielectric bsdf is given as <float> or <string>"),
    ("<bsdf type='measured'><string name='filename' value='nothere.bsdf'/></bsdf>",
     "<string>: no file 'nothere.bsdf' for the measured bsdf"),
    ("<bsdf type='measured'/>", "a measured bsdf needs a 'filename'"),
    ("<bsdf type='bumpmap'><bsdf type='diffuse'/></bsdf>",
     "a bumpmap bsdf needs exactly one nested texture (its height), got 0"),
])
def test_an_approximated_bsdf_takes_what_mitsuba_takes(tmp_path, bsdf, message):
    """A BSDF probvis approximates took any child (a misspelt name, a <point> as a colour, an emitter inside it, a
    blendbsdf of three), then any value under a known name (a bogus distribution, a material beside eta, a string
    for a flag or a colour, a measured BSDF without its file, a bumpmap without its texture): each ignored, exit 0,
    where Mitsuba refuses each."""
    path = write_scene(tmp_path / "bad.xml", sensor() + f"<shape type='rectangle'>{bsdf}</shape>" + LIGHT)
    with pytest.raises(ProbvisError, match=re.escape(message)):
        probvis.load_scene(path)


def test_an_approximated_bsdf_s_rgb_is_taken_where_mitsuba_takes_it(tmp_path):
    """A reflectance of 1.5 given as <rgb> was clamped to 1 and rendered, and an <rgb> was taken for parameters
    that are single numbers: Mitsuba refuses the first on every parameter it reads as an sRGB reflectance (a
    conductor's eta and k are unbounded) and the second as a wrong type. probvis refuses the same, judged
    against Mitsuba 3 (scalar_rgb) parameter by parameter."""
    mi = pytest.importorskip("mitsuba")
    from probvis.scene.mitsuba_xml import (_BSDF_PARAMETERS, _FLAG_PARAMETERS, _IOR_PARAMETERS, _NAME_PARAMETERS,
                                           _NESTED_BSDFS)

    mi.set_variant("scalar_rgb")
    seen = set()
    for kind, names in _BSDF_PARAMETERS.items():
        nested = {f"b{k}": {"type": "diffuse"} for k in range(_NESTED_BSDFS.get(kind, 0))}
        for name in names:
            if name in _FLAG_PARAMETERS | _NAME_PARAMETERS | _IOR_PARAMETERS or name.startswith("alpha") or kind in (
                    "bumpmap", "normalmap"):
                continue
            try:
                mi.load_dict({"type": kind, name: {"type": "rgb", "value": [1.5, 1.5, 1.5]}, **nested})
                theirs = "taken"
            except Exception as exc:
                theirs = ("range" if "Invalid RGB reflectance value" in str(exc) else
                          "type" if "has the wrong type" in str(exc) else str(exc))
            inner = "<bsdf type='diffuse'/>" * _NESTED_BSDFS.get(kind, 0)
            bsdf = f"<bsdf type='{kind}'><rgb name='{name}' value='1.5'/>{inner}</bsdf>"
            path = write_scene(tmp_path / "b.xml", sensor() + f"<shape type='rectangle'>{bsdf}</shape>" + LIGHT)
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    probvis.load_scene(path)
                ours = "taken"
            except ProbvisError as exc:
                ours = ("range" if "is a reflectance" in str(exc) or "weight is between 0 and 1" in str(exc) else
                        "type" if "is given as <float>" in str(exc) else str(exc))
            assert ours == theirs, (kind, name)
            seen.add(theirs)
    assert seen == {"taken", "range", "type"}


def test_a_constant_environment_takes_a_to_world_that_changes_nothing(tmp_path):
    """Every Mitsuba emitter reads a to_world; a constant emitter's was refused as an unsupported parameter."""
    body = sensor() + "<shape type='rectangle'/><emitter type='constant'><rgb name='radiance' value='0.7'/>{}</emitter>"
    plain = probvis.render(write_scene(tmp_path / "a.xml", body.format("")), spp=4, seed=1).image
    turned = probvis.render(write_scene(tmp_path / "b.xml", body.format(
        "<transform name='to_world'><rotate x='1' angle='50'/><scale value='2'/></transform>")), spp=4, seed=1).image
    np.testing.assert_array_equal(plain, turned)
    assert plain.max() > 0


@pytest.mark.parametrize("kind, value", [("roughconductor", "GGX"), ("roughplastic", "Beckmann"),
                                         ("roughdielectric", "Ggx")])
def test_a_microfacet_distribution_is_read_in_any_case(tmp_path, kind, value):
    """Mitsuba lower-cases the distribution's name; 'GGX' was refused as "beckmann or ggx"."""
    bsdf = f"<bsdf type='{kind}'><string name='distribution' value='{value}'/></bsdf>"
    with pytest.warns(UserWarning, match="approximated"):
        probvis.load_scene(write_scene(tmp_path / "d.xml", sensor() + f"<shape type='rectangle'>{bsdf}</shape>"
                                       + LIGHT))


@pytest.mark.parametrize("edit, message", [
    (('<sampler type="independent">', '<sampler type="independent"><integer name="dimension" value="4"/>'),
     "<integer>: unsupported parameter 'dimension' for sampler 'independent'"),
    (('<sampler type="independent">', '<sampler type="independent"><boolean name="jitter" value="true"/>'),
     "unsupported parameter 'jitter' for sampler 'independent'"),
    (('<sampler type="independent">', '<sampler type="independent"><integer name="seed" value="4294967296"/>'),
     "seed must be from 0 to 4294967295, got 4294967296"),
    (('<integer name="bsdf_samples" value="0"/>', '<integer name="bsdf_samples" value="-1"/>'),
     "<integer>: bsdf_samples must not be negative, got -1"),
    (('<float name="fov" value="40"/>', '<float name="focal_length" value="35"/>'),
     "parameter 'focal_length' must be given as <string>"),
    (('<rfilter type="box"/>', '<rfilter type="box"/><string name="pixel_format" value="y"/>'),
     "unknown pixel_format 'y' (Mitsuba's hdrfilm takes rgb, rgba, luminance, luminance_alpha, xyz, xyza)"),
])
def test_sampler_integrator_and_film_parameters_are_mitsuba_s(tmp_path, edit, message):
    """Parameters no sampler of that type takes, a seed beyond Mitsuba's 32 bits, a negative bsdf_samples, a
    focal length as a number and a pixel format Mitsuba does not know were accepted."""
    path = write_scene(tmp_path / "bad.xml", sensor().replace(*edit) + LIGHT + "<shape type='rectangle'/>")
    with pytest.raises(ProbvisError, match=re.escape(message)):
        probvis.load_scene(path)


def test_valid_sampler_and_film_parameters_of_mitsuba_are_taken(tmp_path):
    """orthogonal's own `strength` was refused; `xyz` and `RGB` pixel formats (Mitsuba lower-cases them) were
    refused, `luminance_alpha` too: each is read, the format with the warning that probvis writes RGB."""
    body = sensor().replace('<sampler type="independent">', '<sampler type="orthogonal"><integer name="strength" '
                            'value="2"/><boolean name="jitter" value="false"/>')
    for fmt in ("xyz", "RGB", "luminance_alpha"):
        with pytest.warns(UserWarning):
            probvis.load_scene(write_scene(tmp_path / f"{fmt}.xml", body.replace(
                '<rfilter type="box"/>', f'<rfilter type="box"/><string name="pixel_format" value="{fmt}"/>')
                + LIGHT + "<shape type='rectangle'/>"))
    body = sensor() + LIGHT + ("<shape type='rectangle'><bsdf type='diffuse'><texture type='bitmap' "
                               "name='reflectance'><string name='filename' value='t.png'/><string name='format' "
                               "value='bogus'/></texture></bsdf></shape>")
    with pytest.raises(ProbvisError, match=re.escape("unknown bitmap format 'bogus' (Mitsuba's: auto, variant")):
        probvis.load_scene(write_scene(tmp_path / "fmt.xml", body))


def test_an_instance_s_singular_transform_is_named_at_the_instance(tmp_path):
    """It was named at the line of the shape inside the shapegroup, which has no transform."""
    body = sensor() + LIGHT + """
<shape type="shapegroup" id="g"><shape type="sphere"><float name="radius" value="0.1"/></shape></shape>
<shape type="instance"><ref id="g"/>
<transform name="to_world"><scale x="0"/></transform></shape>"""
    path = write_scene(tmp_path / "inst.xml", body)
    line = next(k for k, text in enumerate(path.read_text().splitlines(), 1) if "<scale x=" in text)
    with pytest.raises(ProbvisError, match=re.escape(f"inst.xml:{line}: <transform>: the instance's to_world is "
                                                     "singular or projective")):
        probvis.load_scene(path)


def test_the_approximated_bsdfs_parameters_are_mitsuba_s(tmp_path):
    """Each name the reader takes for a BSDF it approximates is one Mitsuba 3 takes (no 'unreferenced
    property'), so a scene both accept is read the same, and one Mitsuba refuses is refused."""
    mi = pytest.importorskip("mitsuba")
    from probvis.scene.mitsuba_xml import _BSDF_PARAMETERS, _NESTED_BSDFS

    mi.set_variant("scalar_rgb")
    special = {"material": "Au", "distribution": "beckmann", "nonlinear": True, "sample_visible": True,
               "polarizing": True, "normalmap": {"type": "checkerboard"}, "filename": str(tmp_path / "none")}
    for kind, names in _BSDF_PARAMETERS.items():
        nested = {f"b{k}": {"type": "diffuse"} for k in range(_NESTED_BSDFS.get(kind, 0))}
        extra = {"t": {"type": "checkerboard"}} if kind == "bumpmap" else {}
        for name in names:
            pair = name in ("alpha_u", "alpha_v")  # given together or not at all
            value = {"alpha_u": 0.2, "alpha_v": 0.3} if pair else {name: special.get(name, 0.5)}
            if kind == "normalmap":
                value["normalmap"] = special["normalmap"]
            try:
                mi.load_dict({"type": kind, **value, **nested, **extra})
            except Exception as exc:  # a missing measured file fails after the parameters were read
                assert "unreferenced" not in str(exc), (kind, name, str(exc)[:300])


@pytest.mark.parametrize("edit, message", [
    (('<float name="fov" value="40"/>', '<string name="fov_axis" value="y"/>'),
     "fov_axis applies to 'fov' only (a focal_length spans the 35 mm frame's diagonal)"),
    (('<float name="fov" value="40"/>',
      '<string name="focal_length" value="50mm"/><string name="fov_axis" value="y"/>'),
     "fov_axis applies to 'fov' only"),
    (('<integer name="height"', '<integer name="crop_offset_x" value="7"/><integer name="height"'),
     "the crop window 16x16 at (7, 0) does not fit the 16x16 film"),
])
def test_sensor_parameters_mitsuba_refuses_are_refused(tmp_path, edit, message):
    """fov_axis beside a focal length was dropped silently (even 'bogus'), and a crop offset without a width
    made the window the rest of the film (a 1-pixel-wide image): Mitsuba refuses both."""
    path = write_scene(tmp_path / "bad.xml", sensor().replace(*edit) + LIGHT + "<shape type='rectangle'/>")
    with pytest.raises(ProbvisError, match=re.escape(message)):
        probvis.load_scene(path)


def test_a_second_film_is_refused(tmp_path):
    body = sensor().replace("</sensor>", "<film type='hdrfilm'/></sensor>")
    with pytest.raises(ProbvisError, match=re.escape("<film>: only one film per sensor")):
        probvis.load_scene(write_scene(tmp_path / "bad.xml", body + LIGHT))


@pytest.mark.parametrize("edit, message", [
    (("</sensor>", "<sampler type='independent'/></sensor>"), "<sampler>: only one sampler per sensor"),
    (("<rfilter type=\"box\"/>", "<rfilter type='box'/><rfilter type='gaussian'/>"),
     "<rfilter>: only one reconstruction filter per film"),
    (("value=\"16\"/>", "value=\"1_6\"/>"), "<integer>: '1_6' is not a valid integer"),
    (("value=\"16\"/>", "value=\"\u0661\u0666\"/>"), "<integer>: '\u0661\u0666' is not a valid integer"),
    (("value=\"16\"/>", "value=\"+16\"/>"), "<integer>: '+16' is not a valid integer: Mitsuba reads no '+' sign"),
    (("value=\"40\"/>", "value=\"4_0\"/>"), "<float>: '4_0' is not a valid float"),
    (('name="sample_count" value="4"', 'name="sample_count" value="0"'),
     "<integer>: sample_count must be from 1 to 1048576, got 0"),
    (('name="sample_count" value="4"/>', 'name="sample_count" value="4"/><integer name="seed" value="-3"/>'),
     "<integer>: seed must be from 0 to"),
    (('name="emitter_samples" value="4"', 'name="emitter_samples" value="2000000000"'),
     "<integer>: emitter_samples must be from 1 to 65536, got 2000000000"),
    (('name="emitter_samples" value="4"', 'name="emitter_samples" value="4"/><integer name="shading_samples" '
                                          'value="2"'),
     "<integer>: give either shading_samples or emitter_samples and bsdf_samples, not both"),
    (('<float name="fov"', '<float name="shutter_open" value="0.5"/><float name="fov"'),
     "<float>: shutter_open must not be after shutter_close (as Mitsuba requires"),
    (('name="emitter_samples" value="4"', 'name="emitter_samples" value="0"'),
     "<integer>: emitter_samples must be from 1 to 65536, got 0 (probvis samples emitters only)"),
])
def test_what_mitsuba_refuses_in_a_sensor_is_named(tmp_path, edit, message):
    """A second sampler or filter (the last one won), and Python-only number syntax (underscores, other scripts'
    digits: accepted by int() and float(), not by Mitsuba's parser)."""
    body = sensor().replace(*edit, 1)
    if "emitter_samples" in message:  # with BSDF samples asked for, which probvis warns it does not take
        body = body.replace('name="bsdf_samples" value="0"', 'name="bsdf_samples" value="4"')
    with pytest.raises(ProbvisError, match=re.escape(message)), warnings.catch_warnings():
        warnings.simplefilter("error")  # the error alone: bsdf_samples was warned of first, a second line
        probvis.load_scene(write_scene(tmp_path / "bad.xml", body + LIGHT))


@pytest.mark.parametrize("transform", ["<scale x='0'/>", "<scale value='0'/>", "<scale z='0'/>",
                                       "<matrix value='1 0 0 0 0 1 0 0 0 0 1 0 0 0 0.5 1'/>"])
@pytest.mark.parametrize("shape", ["sphere", "rectangle", "cylinder"])
def test_a_singular_or_projective_shape_transform_is_named(tmp_path, shape, transform):
    """A flattened sphere was a LinAlgError traceback, a flattened rectangle vanished, a projective row was
    ignored: each is refused at the shape's line."""
    body = f"<shape type='{shape}'><transform name='to_world'>{transform}</transform></shape>"
    if shape == "rectangle" and transform == "<scale z='0'/>":
        body = body.replace("<scale z='0'/>", "<scale x='0'/>")
    with pytest.raises(ProbvisError, match=re.escape("<shape>: the shape's to_world is singular or projective")):
        probvis.load_scene(write_scene(tmp_path / "bad.xml", sensor() + body + LIGHT))



@pytest.mark.parametrize("op, mixed", [("<translate x='7' value='1.5,1.5,3'/>", "'x'"),
                                       ("<scale value='0.3' x='2' z='1'/>", "'x', 'z'"),
                                       ("<rotate x='1' value='0,1,0' angle='180'/>", "'x'")])
def test_value_mixed_with_x_y_z_is_refused_as_in_mitsuba(tmp_path, op, mixed):
    """`value` won silently over the x/y/z also given; Mitsuba refuses the mix."""
    body = f"<shape type='sphere'><transform name='to_world'>{op}</transform></shape>"
    with pytest.raises(ProbvisError, match=r"bad.xml:\d+: <(translate|scale|rotate)>: give either 'value' or x/y/z, "
                       + re.escape(f"not both (here also {mixed})")):
        probvis.load_scene(write_scene(tmp_path / "bad.xml", sensor() + body + LIGHT))


def test_a_point_property_mixing_value_and_x_y_z_is_refused(tmp_path):
    """`<point name="center" value="0,0,0" x="1"/>` dropped x without a word; Mitsuba refuses the mix."""
    body = "<shape type='sphere'><point name='center' value='0,0,0' x='1'/></shape>"
    with pytest.raises(ProbvisError, match=r"bad.xml:\d+: <point>: give either 'value' or x/y/z, not both "
                                           r"\(here also 'x'\)"):
        probvis.load_scene(write_scene(tmp_path / "bad.xml", sensor() + body + LIGHT))


def test_a_reflectance_texture_outside_the_unit_range_warns(tmp_path):
    """Mitsuba renders such a bitmap as given; probvis does too, with a warning naming the file and line."""
    from probvis.io import write_pfm

    write_pfm(tmp_path / "t.pfm", np.full((4, 4, 3), -5.0))
    body = sensor() + ("<shape type='rectangle'><bsdf type='diffuse'><texture type='bitmap' name='reflectance'>"
                       "<string name='filename' value='t.pfm'/></texture></bsdf></shape>") + LIGHT
    path = write_scene(tmp_path / "s.xml", body)
    with pytest.warns(UserWarning, match=re.escape(f"{path}:") + r"\d+: the reflectance texture has values from -5"):
        probvis.load_scene(path)


def test_a_scene_without_a_sensor_says_where_and_what_to_add(tmp_path):
    """It was 'the scene has no <sensor>' without line or advice (Mitsuba loads such a file but has nothing to
    render it with)."""
    path = tmp_path / "n.xml"
    path.write_text('<?xml version="1.0"?>\n<scene version="3.0.0">\n' + LIGHT + "</scene>\n")
    with pytest.raises(ProbvisError, match=re.escape(f"{path}:2: <scene>: the scene has no <sensor>: add one (a "
                                                     '<sensor type="perspective"> with its to_world and film)')):
        probvis.load_scene(path)


def test_comments_with_double_hyphens_are_read_as_mitsuba_reads_them(tmp_path):
    """XML forbids '--' inside a comment and a comment ending in '--->'; Mitsuba's parser reads both (probvis said
    'malformed XML: not well-formed'). Lines keep their numbers: an error after such a comment names its line."""
    path = tmp_path / "c.xml"
    text = ('<scene version="3.0.0">\n<!-- a -- b -->\n' + sensor() + "<!-- c\n -- d --->\n" + LIGHT
            + "<!---->\n</scene>\n")
    path.write_text(text)
    scene = probvis.load_scene(path)
    assert scene.n_emitters == 1
    path.write_text(text.replace("</scene>", '<bogus/>\n</scene>'))
    line = text.count("\n", 0, text.index("</scene>")) + 1
    with pytest.raises(ProbvisError, match=re.escape(f"{path}:{line}: ")):
        probvis.load_scene(path)
    path.write_text(text.replace("<!---->", "<!-- open"))
    with pytest.raises(ProbvisError, match="malformed XML"):  # what no parser reads stays an error
        probvis.load_scene(path)
    from probvis.scene.mitsuba_xml import _comments_as_mitsuba_reads_them as lenient

    cdata = b"<![CDATA[ <!-- a--b ]]> <!-- c -- d --->"  # text in a CDATA section keeps its hyphens
    assert lenient(cdata) == b"<![CDATA[ <!-- a--b ]]> <!-- c -  d  -->"


@pytest.mark.parametrize("version", ["banana", "3", "3.0", "3.0.0.0"])
def test_a_scene_version_that_is_not_a_number_is_refused(tmp_path, version):
    """Mitsuba refuses a version of other than three parts too ("Invalid version number: 3.0"; probvis read it)."""
    path = tmp_path / "v.xml"
    path.write_text(f'<scene version="{version}">\n' + sensor() + LIGHT + "</scene>\n")
    with pytest.raises(ProbvisError, match=re.escape(f"{path}:1: <scene>: version must be a version number of three "
                                                     f"parts such as 3.0.0 (as Mitsuba requires), got '{version}'")):
        probvis.load_scene(path)


def test_a_named_index_of_refraction_is_mitsubas_value(tmp_path):
    """`int_ior="diamond"` is 2.419 (it was taken as BK7's 1.5046): the diffuse stand-in's reflectance is the
    Fresnel reflectance at normal incidence of that index against air."""
    body = ("<shape type='rectangle'><bsdf type='dielectric'><string name='int_ior' value='diamond'/>"
            "<string name='ext_ior' value='air'/></bsdf></shape>")
    with pytest.warns(UserWarning, match="rendered as diffuse"):
        scene = probvis.load_scene(write_scene(tmp_path / "s.xml", sensor() + body + LIGHT))
    eta = 2.419 / 1.00028
    assert np.isclose(scene.reflectance.max(), ((eta - 1) / (eta + 1)) ** 2)


@pytest.mark.parametrize("key, value", [("component_format", "banana"), ("file_format", "jpeg")])
def test_a_film_format_mitsuba_does_not_know_is_named(tmp_path, key, value):
    body = sensor().replace("<rfilter", f"<string name='{key}' value='{value}'/><rfilter", 1)
    with pytest.raises(ProbvisError, match=re.escape(f"<film>: unknown {key} '{value}'")):
        probvis.load_scene(write_scene(tmp_path / "bad.xml", body + LIGHT))


def test_a_default_s_name_may_be_any_word(tmp_path):
    """`$r\u00e4` was read as `$r` and refused as undefined; Mitsuba substitutes any declared name."""
    body = ("<default name='r\u00e4' value='0.25'/>" + sensor() +
            "<shape type='sphere'><float name='radius' value='$r\u00e4'/></shape>" + LIGHT)
    scene = probvis.load_scene(write_scene(tmp_path / "s.xml", body))
    assert np.isclose(np.abs(scene.triangles[scene.tri_emitter < 0]).max(), 0.25, rtol=0.01)


@pytest.mark.parametrize("name", ["m.txt", "mesh"])
def test_a_mesh_is_read_by_its_shape_type_not_its_extension(tmp_path, name):
    """Mitsuba reads `type='obj'` as OBJ whatever the file is called; probvis chose the reader by extension."""
    (tmp_path / name).write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    body = sensor() + f"<shape type='obj'><string name='filename' value='{name}'/></shape>" + LIGHT
    scene = probvis.load_scene(write_scene(tmp_path / "s.xml", body))
    assert (scene.tri_emitter < 0).sum() == 1


def test_a_shapegroup_nothing_instances_is_still_loaded(tmp_path):
    """Mitsuba loads a group's shapes when it is defined: a missing mesh in an unused group went unnoticed."""
    body = (sensor() + "<shape type='shapegroup' id='g'><shape type='obj'><string name='filename' "
            "value='nothere.obj'/></shape></shape>" + LIGHT)
    with pytest.raises(ProbvisError, match="mesh file not found: .*nothere.obj"):
        probvis.load_scene(write_scene(tmp_path / "s.xml", body))


def test_a_sensor_s_spectral_response_is_approximated_or_refused(tmp_path):
    """`srf` was parsed and ignored without a word; a negative one is no response at all."""
    body = sensor().replace("<float name=\"fov\"", "<rgb name='srf' value='0.5'/><float name=\"fov\"", 1)
    with pytest.warns(UserWarning, match="sensor 'srf' ignored: probvis renders RGB"):
        probvis.load_scene(write_scene(tmp_path / "s.xml", body + LIGHT))
    with pytest.raises(ProbvisError, match="srf \\(spectral response\\) must not be negative"):
        probvis.load_scene(write_scene(tmp_path / "n.xml", body.replace("'0.5'", "'-1'") + LIGHT))


@pytest.mark.parametrize("ior, reflectance", [(("1e308", "1e-308"), 1.0), (("1e-308", "1e308"), 1.0),
                                              (("1.5", "1"), 0.04), (("1e200", "1e200"), 0.0)])
def test_a_dielectric_approximated_at_any_contrast_is_finite(tmp_path, ior, reflectance):
    """The Fresnel reflectance at normal incidence of an extreme index ratio was inf / inf: NaN pixels, exit 0."""
    body = sensor() + LIGHT + (f"<shape type='rectangle'><bsdf type='dielectric'><float name='int_ior' value='{ior[0]}'/>"
                               f"<float name='ext_ior' value='{ior[1]}'/></bsdf></shape>")
    with pytest.warns(UserWarning, match="rendered as diffuse"):
        scene = probvis.load_scene(write_scene(tmp_path / "d.xml", body))
    assert np.allclose(scene.reflectance[-1], reflectance)


@pytest.mark.parametrize("camera, message", [
    ("<float name='fov' value='179.9999999'/>", "fov 179.9999999 makes the view 179.9999999 degrees wide"),
    ("<string name='focal_length' value='1e-7mm'/>", "focal_length 1e-7mm makes the view 179.9999993 degrees wide"),
    # the ratio overflowed: NumPy's warning, then 'fov must be between 0 and 180 degrees, got 180' (no fov given)
    ("<string name='focal_length' value='1e-320mm'/>", "focal_length 1e-320mm makes the view 180 degrees wide"),
    ("<string name='focal_length' value='1e-320mm'/>", "focal_length 1e-320mm makes the view 180 degrees wide"),
])
def test_a_view_so_wide_the_scene_shrinks_to_a_dot_is_refused(tmp_path, camera, message):
    """A perspective camera near 180 degrees rendered an all-black image without a word."""
    body = sensor().replace("<float name=\"fov\" value=\"40\"/>", camera)
    assert camera in body
    with pytest.raises(ProbvisError, match=re.escape(message)):
        probvis.load_scene(write_scene(tmp_path / "wide.xml", body + LIGHT))


def test_a_view_so_tall_the_scene_shrinks_to_a_dot_is_refused(tmp_path):
    """The refusal read the width alone: a 1 x 4096 film with fov 45 across x is 179.93 degrees tall, and rendered
    three lit pixels of 4096 without a word (a 4096 x 1 one, as wide, was refused)."""
    body = sensor(w=1, h=4096).replace("<float name=\"fov\" value=\"40\"/>",
                                       "<float name='fov' value='45'/><string name='fov_axis' value='x'/>")
    with pytest.raises(ProbvisError, match=r"fov 45 makes the view 179\.93\d* degrees tall \(at most 179\.5"):
        probvis.load_scene(write_scene(tmp_path / "tall.xml", body + LIGHT))
    at_limit = sensor(w=3, h=5).replace("<float name=\"fov\" value=\"40\"/>",
                                        "<float name='fov' value='179.5'/><string name='fov_axis' value='y'/>")
    probvis.load_scene(write_scene(tmp_path / "limit.xml", at_limit + LIGHT))  # at the limit, a few ulps over it
    path = write_scene(tmp_path / "ok.xml", sensor() + LIGHT)  # 40 degrees across x: fine at 16 x 16
    with pytest.raises(ProbvisError, match=r"1x8192 film is 179\.9\d* degrees tall, more than 179\.5"):
        probvis.render(path, resolution=(1, 8192))


def test_an_emission_spectrum_outside_the_srgb_gamut_is_clamped_with_a_warning(tmp_path):
    """A narrow green line has a negative red in sRGB: clamped to 0 (it was refused as 'must be non-negative')."""
    body = sensor() + LIGHT.replace('<rgb name="radiance" value="1"/>',
                                    '<spectrum name="radiance" value="500:0, 520:10, 540:0"/>')
    with pytest.warns(UserWarning, match="outside the sRGB gamut"):
        scene = probvis.load_scene(write_scene(tmp_path / "green.xml", body))
    rad = scene.emitter_radiance[0]
    assert rad.min() == 0.0 and rad[1] > 0


def test_a_bumpmap_may_reference_its_texture(tmp_path):
    """`<ref>` to a texture inside a bumpmap is the texture, not the wrapped BSDF."""
    body = sensor() + ("<texture type='checkerboard' id='bumps'/><bsdf type='diffuse' id='base'>"
                       "<rgb name='reflectance' value='0.3'/></bsdf>"
                       "<shape type='rectangle'><bsdf type='bumpmap'><ref id='bumps'/><ref id='base'/></bsdf></shape>")
    with pytest.warns(UserWarning, match="bumpmap"):
        scene = probvis.load_scene(write_scene(tmp_path / "bump.xml", body + LIGHT))
    np.testing.assert_allclose(scene.reflectance[scene.tri_material[0]], 0.3)


def test_a_shape_without_area_is_left_out_with_a_warning(tmp_path):
    """A sphere too small for its position's precision (its corners round to one point) vanished without a word."""
    body = sensor() + LIGHT + ("<shape type='sphere'><float name='radius' value='1e-20'/>"
                               "<point name='center' x='1' y='1' z='1'/></shape>")
    with pytest.warns(UserWarning, match=r"shape 'sphere' has no area \(all 3968 of its triangles are degenerate"):
        probvis.load_scene(write_scene(tmp_path / "tiny.xml", body))


@pytest.mark.parametrize("shape, why", [
    ("<shape type='sphere'><float name='radius' value='0'/></shape>", "its radius is 0"),
    ("<shape type='cylinder'><point name='p0' x='1' y='1' z='1'/><point name='p1' x='1' y='1' z='1'/></shape>",
     "its radius is 0 or p0 = p1"),
    ("<shape type='cylinder'><float name='radius' value='0'/></shape>", "its radius is 0 or p0 = p1")])
def test_an_analytic_shape_without_area_is_left_out_as_a_mesh_s_is(tmp_path, shape, why):
    """A sphere of radius 0 and a cylinder with p0 = p1 were refused, where Mitsuba 3.9.1 renders the rest of
    the scene (sweep 37) and probvis leaves out a mesh without area with a warning: now the same. An area
    emitter on one emits nothing: left out with a warning beside other emitters, as Mitsuba renders it (sweep
    38), refused where it would be the scene's only one."""
    with pytest.warns(UserWarning, match=re.escape(f"has no area ({why}): it is left out")):
        scene = probvis.load_scene(write_scene(tmp_path / "s.xml", sensor() + LIGHT + shape))
    assert scene.n_triangles == probvis.load_scene(write_scene(tmp_path / "l.xml", sensor() + LIGHT)).n_triangles
    emitting = shape.replace("</shape>", "<emitter type='area'><rgb name='radiance' value='1'/></emitter></shape>")
    with pytest.warns(UserWarning, match=re.escape(f"({why}): it is left out with its area emitter, which emits")):
        lit = probvis.load_scene(write_scene(tmp_path / "e.xml", sensor() + LIGHT + emitting))
    assert lit.n_emitters == 1 and lit.n_triangles == scene.n_triangles
    with pytest.raises(ProbvisError, match=re.escape(f"an area emitter on a shape without area ({why}) emits "
                                                     "nothing, and the scene has no other emitter")):
        probvis.load_scene(write_scene(tmp_path / "d.xml", sensor() + "<shape type='cube'/>" + emitting))


@pytest.mark.parametrize("where", ["far", "beside a far vertex"])
def test_small_shapes_keep_their_faces_wherever_they_are(tmp_path, where):
    """Whether a face had area was judged against the largest coordinate of its whole mesh: a 0.4-unit cube at
    x = 5e6 was left out as 'without area', and a sphere in one file with a vertex at 1e8 was dropped silently."""
    if where == "far":
        body = ("<shape type='cube'><transform name='to_world'><scale value='0.2'/><translate x='5e6'/>"
                "</transform></shape>")
    else:
        import trimesh

        sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
        lines = [f"v {x} {y} {z}" for x, y, z in sphere.vertices] + ["v 1e8 0 0"]
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in sphere.faces]
        (tmp_path / "m.obj").write_text("\n".join(lines) + "\n")
        body = "<shape type='obj'><string name='filename' value='m.obj'/></shape>"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scene = probvis.load_scene(write_scene(tmp_path / "s.xml", sensor() + LIGHT + body))
    assert scene.dropped_degenerate == 0 and scene.n_triangles == 2 + (12 if where == "far" else 1280)


@pytest.mark.parametrize("up", [[0, 1e300, 0], [0, 1e-13, 0], [0, 1e-20, 0], [2e-13, 1e-13, 0]])
def test_an_up_vector_of_any_length_is_a_direction(up):
    """up = 1e300 overflowed in the cross product (numpy warnings, then 'parallel to the viewing direction'); a
    short up (1e-13, perpendicular to the view) was refused as parallel to it, where Mitsuba renders."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_allclose(tf.look_at([0, 0, 4], [0, 0, 0], up),
                                   tf.look_at([0, 0, 4], [0, 0, 0], np.array(up) / np.abs(up).max()))
    with pytest.raises(ValueError, match="parallel to the viewing direction"):
        tf.look_at([0, 0, 4], [0, 0, 0], [1e-20, 0, 1e-6])


def test_huge_normals_and_light_directions_are_directions(tmp_path):
    """A file's normal of 1e200 and a directional light's direction of 1e300 overflowed (NumPy warnings, then a
    zero or NaN direction and exit 0); an ASCII PLY float beyond float32 warned before its error."""
    (tmp_path / "m.obj").write_text("v -1 -1 0\nv 1 -1 0\nv 0 1 0\nvn 0 0 1e200\nf 1//1 2//1 3//1\n")
    body = sensor(sr=1) + LIGHT + ("<shape type='obj'><string name='filename' value='m.obj'/>"
                               "<boolean name='face_normals' value='false'/></shape>"
                               "<emitter type='directional'><vector name='direction' x='0' y='0' z='-1e300'/>"
                               "</emitter>")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scene = probvis.load_scene(write_scene(tmp_path / "huge.xml", body))
    obj = scene.shapes[1]
    np.testing.assert_allclose(scene.vertex_normals[obj.first_triangle].reshape(-1, 3), np.tile([0, 0, 1.0], (3, 1)))
    np.testing.assert_allclose(scene.emitter_axis[scene.n_emitters - 1], [0, 0, -1.0])
    (tmp_path / "f.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                                    "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
                                    "end_header\n0 0 0\n1e39 0 0\n0 1 0\n3 0 1 2\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ProbvisError, match=r"f.ply:11: mesh f.ply has NaN or infinite vertex coordinates"):
            shapes.load_mesh(tmp_path / "f.ply")


def test_a_mask_says_its_opacity_is_ignored(tmp_path):
    """The warning said 'visibility is exact', but Mitsuba's mask lets shadow rays through and probvis's does not."""
    body = sensor() + LIGHT + ("<shape type='rectangle'><bsdf type='mask'><float name='opacity' value='0'/>"
                               "<bsdf type='diffuse'/></bsdf></shape>")
    with pytest.warns(UserWarning, match=r"bsdf 'mask' .* opaque: its opacity is ignored.*\(visibility approximated\)"):
        probvis.load_scene(write_scene(tmp_path / "mask.xml", body))


def test_a_scene_path_that_loops_is_named_as_such(tmp_path):
    """A symbolic link loop was 'scene file not found'."""
    (tmp_path / "a.xml").symlink_to(tmp_path / "b.xml")
    (tmp_path / "b.xml").symlink_to(tmp_path / "a.xml")
    with pytest.raises(ProbvisError, match="a.xml: a symbolic link that loops"):
        probvis.load_scene(tmp_path / "a.xml")
    (tmp_path / "gone.xml").symlink_to(tmp_path / "nothing.xml")
    with pytest.raises(ProbvisError, match="gone.xml: a symbolic link that points to nothing"):
        probvis.load_scene(tmp_path / "gone.xml")


@pytest.mark.parametrize("link", ["t.png", "d/t.png"])
@pytest.mark.parametrize("shape", [
    "<shape type='rectangle'><bsdf type='diffuse'><texture type='bitmap' name='reflectance'>"
    "<string name='filename' value='{link}'/></texture></bsdf></shape>",
    "<emitter type='envmap'><string name='filename' value='{link}'/></emitter>",
    "<shape type='obj'><string name='filename' value='{link}'/></shape>",
    "<shape type='serialized'><string name='filename' value='{link}'/></shape>"])
def test_inputs_that_loop_are_named_at_their_line(tmp_path, shape, link):
    """A texture, environment map or mesh that is a loop of symbolic links (or sits in a folder that is one) was
    a RuntimeError from Path.resolve, or 'mesh file not found'."""
    (tmp_path / "t.png").symlink_to("t.png")
    (tmp_path / "d").symlink_to("d")
    body = sensor() + LIGHT + shape.format(link=link)
    with pytest.raises(ProbvisError, match=r"s.xml:\d+: .*t.png: a symbolic link that loops"):
        probvis.load_scene(write_scene(tmp_path / "s.xml", body))


def test_a_parameter_name_with_other_characters_is_substituted_as_mitsuba_does(tmp_path):
    """Mitsuba replaces '$' + each declared name literally: `<default name="my-fov">` is usable as $my-fov (it was
    'undefined parameter $my'); an undeclared name is still named."""
    body = sensor().replace('value="40"', 'value="$my-fov"') + LIGHT
    path = write_scene(tmp_path / "s.xml", body, '<default name="my-fov" value="30"/>')
    assert probvis.load_scene(path).camera.fov_x == pytest.approx(30.0)
    path = write_scene(tmp_path / "t.xml", body.replace("$my-fov", "$fov2"), '<default name="my-fov" value="30"/>')
    with pytest.raises(ProbvisError, match=re.escape("undefined parameter '$fov2'")):
        probvis.load_scene(path)


def test_a_declared_name_before_more_letters_is_substituted_as_mitsuba_does(tmp_path):
    """Mitsuba replaces '$' + each declared name wherever it stands: '$f5' with f = 1 is 15 (it was 'undefined
    parameter $f5', advising to declare f5), also when the value comes from -D; the longest declared name wins."""
    body = sensor().replace('value="40"', 'value="$f5"') + LIGHT
    path = write_scene(tmp_path / "s.xml", body, '<default name="f" value="1"/>')
    assert probvis.load_scene(path).camera.fov_x == pytest.approx(15.0)
    assert probvis.load_scene(path, f="2").camera.fov_x == pytest.approx(25.0)
    path = write_scene(tmp_path / "t.xml", body, '<default name="f" value="1"/><default name="f5" value="30"/>')
    assert probvis.load_scene(path).camera.fov_x == pytest.approx(30.0)


def test_alias_path_spectrum_files_and_a_named_emitter_load_as_in_mitsuba(tmp_path):
    """Valid Mitsuba 3 that probvis refused: `<alias>` (read as a duplicate id), `<path>` (a folder searched for
    files), a `<spectrum filename>` (.spd lines) and `name` on a nested emitter; each gives the scene that its
    spelt-out equivalent gives."""
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "q.obj").write_text("v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nf 1 2 3\nf 1 3 4\n")
    (tmp_path / "r.spd").write_text("# wavelength value\n400 0.2\n550 0.8  # green\n\n700 0.4\n")
    body = sensor() + """<path value="sub"/><bsdf type="diffuse" id="a">
        <spectrum name="reflectance" filename="r.spd"/></bsdf><alias id="a" as="b"/>
        <shape type="obj"><string name="filename" value="q.obj"/><ref id="b"/></shape>
        <shape type="rectangle"><transform name="to_world"><translate z="2"/></transform>
        <emitter type="area" name="emitter"><rgb name="radiance" value="1"/></emitter></shape>"""
    scene = probvis.load_scene(write_scene(tmp_path / "s.xml", body))
    spelt = body.replace('filename="r.spd"', 'value="400:0.2, 550:0.8, 700:0.4"').replace('<path value="sub"/>', "")
    spelt = spelt.replace('value="q.obj"', 'value="sub/q.obj"').replace(' name="emitter"', "")
    spelt = spelt.replace('<alias id="a" as="b"/>', "").replace('<ref id="b"/>', '<ref id="a"/>')
    expected = probvis.load_scene(write_scene(tmp_path / "t.xml", spelt))
    np.testing.assert_array_equal(scene.triangles, expected.triangles)
    np.testing.assert_array_equal(scene.reflectance[scene.tri_material], expected.reflectance[expected.tri_material])
    # a <path> after the files it finds, and an alias of a shape (which nothing can refer to), as Mitsuba loads them
    later = body.replace('<path value="sub"/>', "").replace('<shape type="obj">', '<shape type="obj" id="m">')
    later += '<alias id="m" as="n"/><path value="sub"/>'
    np.testing.assert_array_equal(probvis.load_scene(write_scene(tmp_path / "v.xml", later)).triangles,
                                  expected.triangles)
    assert not np.allclose(scene.reflectance[scene.tri_material[0]], scene.reflectance[scene.tri_material[0]][0])
    for bad, message in [('<alias id="zz" as="c"/>', "alias of unknown id 'zz'"),
                         ('<alias id="a" as="a"/>', "duplicate id 'a'"),
                         ('<path value="nowhere"/>', "folder .*nowhere' not found"),
                         ('<bsdf type="diffuse" id="x"><spectrum name="reflectance" filename="bad.spd"/></bsdf>',
                          r"bad.spd:2: expected a wavelength and a value \(two finite numbers\), got '500 0.5 1'"),
                         ('<bsdf type="diffuse" id="x"><spectrum name="reflectance" filename="nan.spd"/></bsdf>',
                          r"nan.spd:3: expected a wavelength and a value \(two finite numbers\), got '600 x'")]:
        (tmp_path / "bad.spd").write_text("400 0.5\n500 0.5 1\n")
        (tmp_path / "nan.spd").write_text("400 0.5\n# a comment\n600 x\n")
        with pytest.raises(ProbvisError, match=message):
            probvis.load_scene(write_scene(tmp_path / "u.xml", body + bad))


def test_an_empty_define_name_is_refused():
    """An empty name joined the `$name` pattern and took over every parameter ('$res' read as '$' + 'res')."""
    with pytest.raises(ProbvisError, match="defines: a parameter name is empty"):
        probvis.load_scene("quad-shadow", **{"": "3"})


def test_a_parameter_value_that_is_no_string_or_number_is_refused():
    """`defines={"res": 8}` was one parameter named 'defines', with a warning worded for the command line."""
    with pytest.raises(ProbvisError, match=r"parameter defines=\{'res': 8\}: a scene parameter's value is a string "
                                           r"or a number; give each parameter its own: load_scene\(path, "):
        probvis.load_scene("quad-shadow", defines={"res": 8})
    with pytest.raises(ProbvisError, match=r"parameter res=\[8\]: .* or render\(path, defines=\{'name': value"):
        probvis.render("quad-shadow", defines={"res": [8]})  # the advice fits render's defines too (sweep 42)
    assert probvis.load_scene("quad-shadow", res=np.int64(8)).camera.width == 8
    assert probvis.load_scene("quad-shadow", strict=np.True_, res=8).camera.width == 8  # as render's flags


def test_a_default_may_refer_to_one_declared_before_it(tmp_path):
    """`<default name="res" value="$b"/>` after b's: substituted there, with -D b=... too."""
    path = write_scene(tmp_path / "s.xml", sensor(w="$res", h="$res") + LIGHT,
                       '<default name="b" value="6"/><default name="res" value="$b"/>')
    assert probvis.load_scene(path).camera.width == 6
    assert probvis.load_scene(path, b=4).camera.width == 4
    late = write_scene(tmp_path / "late.xml", sensor(w="$res", h="$res") + LIGHT, '<default name="res" value="$b"/>')
    assert probvis.load_scene(late, res=5).camera.width == 5  # given with -D: its default's value is not read


def test_parameters_named_path_or_strict_are_parameters(tmp_path, capsys):
    """`-D path=4` collided with load_scene's own arguments: a TypeError traceback from the command line, the API
    and an experiment's defines."""
    from probvis.cli import main
    from probvis.scene import open_scene

    body = sensor().replace('value="16"/><integer name="height"', 'value="$path"/><integer name="height"')
    path = write_scene(tmp_path / "p.xml", body + LIGHT, '<default name="path" value="8"/><default name="strict" '
                                                          'value="1"/>')
    assert open_scene(path, {"path": "4", "strict": "2"}).camera.width == 4
    assert probvis.load_scene(path, path=4).camera.width == 4
    assert main(["render", str(path), "-D", "path=4", "-D", "strict=3", "--spp", "1", "--shadow-rays", "1",
                 "-o", str(tmp_path / "o.exr"), "-q"]) == 0
    assert main(["info", str(path), "-D", "path=5", "--json"]) == 0
    assert '"width": 5' in capsys.readouterr().out
    r = probvis.render(str(path), spp=1, shadow_rays=1, defines={"path": 6, "strict": 1})
    assert r.image.shape[1] == 6
    with pytest.raises(ProbvisError, match="built-in scene 'quad-shadow' has no parameter 'strict'"):
        probvis.render("quad-shadow", spp=1, shadow_rays=1, defines={"strict": 1, "res": 8})


@pytest.mark.parametrize("scale, shift", [(1e-9, 0.0), (1.0, 1e9)])
def test_a_scene_its_ray_offsets_would_blur_is_warned_about(tmp_path, scale, shift):
    """Shadow rays leave their surfaces 1e-9 × (1 + the largest coordinate) away, as Mitsuba's ray epsilon: a scene
    scaled by 1e-9, or one unit-sized at x = 1e9, lost its small shadows without a word."""
    t = f"<scale value='{scale}'/><translate x='{shift}'/>"
    body = (sensor(origin=f"{shift}, 0, {4 * scale}", target=f"{shift}, 0, 0").replace(
        '<float name="fov"', f'<float name="near_clip" value="{scale * 1e-3}"/><float name="fov"')
            + f"<shape type='rectangle'><transform name='to_world'>{t}</transform></shape>"
            + f"<shape type='rectangle'><transform name='to_world'><translate z='2'/>{t}</transform>"
            + "<emitter type='area'><rgb name='radiance' value='1'/></emitter></shape>")
    with pytest.warns(UserWarning, match=r"shadow rays leave their surfaces up to .* of the scene\), which can lose "
                                         r"small shadows; scale the scene nearer to unit size"):
        probvis.load_scene(write_scene(tmp_path / "s.xml", body))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        probvis.load_scene(write_scene(tmp_path / "u.xml", sensor() + LIGHT))


def test_an_id_made_of_a_parameter_is_substituted_as_every_attribute_is(tmp_path):
    """`<bsdf id="$m">` kept its id raw while `<ref id="$m">` was substituted: a correct scene was refused with
    'reference to unknown id'. An id made of a parameter that collides with another is a duplicate."""
    grey = "<shape type='sphere'><float name='radius' value='0.2'/><ref id='{ref}'/></shape>"
    bsdf = "<bsdf type='diffuse' id='$m'><rgb name='reflectance' value='0.25'/></bsdf>"
    for ref in ("$m", "dull"):
        path = write_scene(tmp_path / "s.xml", sensor() + bsdf + grey.format(ref=ref) + LIGHT,
                           "<default name='m' value='dull'/>")
        scene = probvis.load_scene(path)
        assert np.isclose(scene.reflectance, 0.25).all(axis=1).any()  # the sphere has the bsdf named
    twice = bsdf + "<bsdf type='diffuse' id='dull'/>"
    path = write_scene(tmp_path / "t.xml", sensor() + twice + grey.format(ref="dull") + LIGHT,
                       "<default name='m' value='dull'/>")
    with pytest.raises(ProbvisError, match=r"t.xml:\d+: <bsdf>: duplicate id 'dull' \(first defined on line"):
        probvis.load_scene(path)


def test_parameters_that_expand_exponentially_are_refused_before_they_grow(tmp_path):
    """Defaults made of defaults ('billion laughs' through $parameters): a 2 KB file asked for gigabytes and
    failed as 'out of memory ... its meshes and images', or quoted a 50 MB value in a one-line error."""
    levels = ["<default name='g' value='" + "x" * 50 + "'/>"]
    for name, inner in zip("fedcba", "gfedcb"):
        levels.append(f"<default name='{name}' value='{('$' + inner) * 10}'/>")
    path = write_scene(tmp_path / "s.xml", sensor() + LIGHT, "".join(levels))
    with pytest.raises(ProbvisError, match=r"<default>: attribute 'value' expands to 5,000,000 characters through "
                                           r"its parameters, more than 1,048,576"):
        probvis.load_scene(path)


def test_errors_name_the_command_line_parameter_a_value_came_from(tmp_path):
    path = write_scene(tmp_path / "s.xml", sensor().replace('value="40"', 'value="$fov"') + LIGHT,
                       "<default name='fov' value='30'/>")
    with pytest.raises(ProbvisError, match=r"s.xml:\d+: <float>: .* \(with -D fov=wide\)$"):
        probvis.load_scene(path, fov="wide")


def test_unused_film_formats_are_named(tmp_path):
    body = sensor().replace("<rfilter", "<string name='pixel_format' value='rgba'/><rfilter", 1)
    with pytest.warns(UserWarning, match="hdrfilm's pixel_format 'rgba' not used: probvis writes RGB float32"):
        probvis.load_scene(write_scene(tmp_path / "t.xml", body + LIGHT))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # Mitsuba's defaults, and float32 components, are what probvis writes
        body = sensor().replace("<rfilter", "<string name='component_format' value='float32'/><rfilter", 1)
        probvis.load_scene(write_scene(tmp_path / "u.xml", body + LIGHT))


MATERIAL = "<bsdf type='diffuse' id='m'><rgb name='reflectance' value='$refl'/></bsdf>"
FLOOR = "<shape type='rectangle'><transform name='to_world'><scale value='2'/></transform>{bsdf}</shape>"


@pytest.mark.parametrize("case", ["top", "in-shape", "root-element", "nested"])
def test_an_included_file_reads_as_if_pasted_in_as_in_mitsuba(tmp_path, case):
    """Mitsuba replaces an <include> by the included <scene>'s elements, or by its root element, looked for beside
    the including file: its render equals the pasted scene's, and so does probvis's (probvis refused <include>)."""
    (tmp_path / "sub").mkdir()
    head = "<default name='refl' value='0.3'/>" + sensor() + LIGHT
    pasted = write_scene(tmp_path / "pasted.xml", head + MATERIAL + FLOOR.format(bsdf="<ref id='m'/>"))
    wrap = "<scene version='3.0.0'>{}</scene>"
    if case == "top":
        (tmp_path / "sub" / "m.xml").write_text(wrap.format(MATERIAL))
        body = "<include filename='sub/m.xml'/>" + FLOOR.format(bsdf="<ref id='m'/>")
    elif case == "in-shape":
        (tmp_path / "sub" / "m.xml").write_text(wrap.format(MATERIAL.replace(" id='m'", "")))
        body = FLOOR.format(bsdf="<include filename='sub/m.xml'/>")
    elif case == "root-element":
        (tmp_path / "sub" / "m.xml").write_text(MATERIAL.replace("<bsdf ", "<bsdf version='3.0.0' "))
        body = "<include filename='sub/m.xml'/>" + FLOOR.format(bsdf="<ref id='m'/>")
    else:  # sub/a.xml includes b.xml beside it
        (tmp_path / "sub" / "a.xml").write_text(wrap.format("<include filename='b.xml'/>"))
        (tmp_path / "sub" / "b.xml").write_text(wrap.format(MATERIAL))
        body = "<include filename='sub/a.xml'/>" + FLOOR.format(bsdf="<ref id='m'/>")
    included = write_scene(tmp_path / "s.xml", head + body)
    assert np.array_equal(probvis.render(included, spp=2).image, probvis.render(pasted, spp=2).image)
    assert tmp_path / "sub" / "m.xml" in probvis.load_scene(included).inputs or case == "nested"
    if importlib.util.find_spec("mitsuba") is not None:
        import mitsuba as mi

        mi.set_variant("scalar_rgb")
        assert np.array_equal(*(np.array(mi.render(mi.load_file(str(f)), seed=1, spp=4)) for f in (included, pasted)))


def test_an_include_s_filename_takes_parameters_as_in_mitsuba(tmp_path):
    """`<include filename="$part.xml"/>` reads the file its parameter names, from the <default> above it or -D,
    as Mitsuba substitutes it (probvis refused parameters there)."""
    head = "<default name='refl' value='0.3'/><default name='part' value='a'/>" + sensor() + LIGHT
    wrap = "<scene version='3.0.0'>{}</scene>"
    (tmp_path / "a.xml").write_text(wrap.format(MATERIAL))
    (tmp_path / "b.xml").write_text(wrap.format(MATERIAL.replace("$refl", "0.9")))
    body = "<include filename='$part.xml'/>" + FLOOR.format(bsdf="<ref id='m'/>")
    scene = write_scene(tmp_path / "s.xml", head + body)
    for part, refl in (("a", 0.3), (None, 0.3), ("b", 0.9)):
        loaded = probvis.load_scene(scene, **({} if part is None else {"part": part}))
        assert loaded.reflectance[loaded.tri_material[-1]][0] == pytest.approx(refl)  # the floor, last
    if importlib.util.find_spec("mitsuba") is not None:
        import mitsuba as mi

        mi.set_variant("scalar_rgb")
        mi.load_file(str(scene), part="b")  # a scene Mitsuba reads


@pytest.mark.parametrize("files, body, message", [
    ({}, "<include filename='none.xml'/>", r"s.xml:\d+: <include>: included file 'none.xml' not found"),
    ({"a.xml": "<scene version='3.0.0'><include filename='s.xml'/></scene>"}, "<include filename='a.xml'/>",
     r"a.xml:1: <include>: 's.xml' includes itself \(s.xml -> a.xml -> s.xml\)"),
    ({}, "<include filename='$f.xml'/>", r"s.xml:\d+: <include>: undefined parameter '\$f'"),
    ({}, "<include filename='$f.xml'/><default name='f' value='a'/>",
     r"s.xml:\d+: <include>: parameter '\$f' is declared on line \d+, after this use"),
    ({}, "<include filename='a.xml' other='1'/>", r"s.xml:\d+: <include>: an <include> takes one attribute"),
    ({"a.xml": "<scene version='3.0.0'>\n\n<shape type='rectangle'><float name='nope' value='1'/></shape></scene>"},
     "<include filename='a.xml'/>", r"a.xml:3: <float>: unsupported parameter 'nope'"),
    ({"a.xml": "<scene version='3.0.0'><bsdf type='diffuse' id='m'/></scene>"},
     "<bsdf type='diffuse' id='m'/><include filename='a.xml'/>", r"a.xml:1: <bsdf>: duplicate id 'm' \(first "
                                                                  r"defined on .*s.xml:\d+\)"),
])
def test_an_include_that_cannot_be_read_names_its_file_and_line(tmp_path, files, body, message):
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    with pytest.raises(ProbvisError, match=message):
        probvis.load_scene(write_scene(tmp_path / "s.xml", sensor() + LIGHT + body))


def test_files_that_include_each_other_many_times_over_are_refused(tmp_path, monkeypatch):
    """Ten includes of a file that includes the next ten times, six deep: a million elements from a few kilobytes."""
    monkeypatch.setattr(mitsuba_xml, "MAX_INCLUDED", 5_000)
    for i in range(6):
        inner = f"<include filename='l{i + 1}.xml'/>" * 10 if i < 5 else "<bsdf type='diffuse'/>" * 10
        (tmp_path / f"l{i}.xml").write_text(f"<scene version='3.0.0'>{inner}</scene>")
    with pytest.raises(ProbvisError, match=r"l4.xml:1: <include>: the includes bring more than 5,000 elements"):
        probvis.load_scene(write_scene(tmp_path / "s.xml", sensor() + LIGHT + "<include filename='l0.xml'/>"))


@pytest.mark.parametrize("transform, radius", [('<scale x="4" y="1" z="1"/>', 0.8),  # 0.2 times x's 4
                                               ('<matrix value="1 2 0 0  0 1 0 0  0 0 1 0  0 0 0 1"/>',
                                                0.2 / np.sqrt(2))])  # the stretch of that shear: x's 1/sqrt(2)
def test_a_sphere_stretched_or_sheared_stays_round_as_in_mitsuba(tmp_path, transform, radius):
    """A non-uniform scale or a shear made an ellipsoid where Mitsuba renders a round sphere (with a warning) of
    the radius the transform's stretch gives its x axis; a lit ellipsoid where Mitsuba's sphere enclosed the light
    and its image was black."""
    body = sensor() + LIGHT + (f"<shape type='sphere'><float name='radius' value='0.2'/><transform name='to_world'>"
                               f"{transform}<translate y='0.5'/></transform></shape>")
    with pytest.warns(UserWarning, match="the sphere's to_world has a non-uniform scale or a shear: rendered round"):
        scene = probvis.load_scene(write_scene(tmp_path / "s.xml", body))
    sphere = scene.triangles[scene.tri_emitter < 0].reshape(-1, 3)
    np.testing.assert_allclose(np.linalg.norm(sphere - [0.0, 0.5, 0.0], axis=1), radius, rtol=1e-9)


def test_an_area_emitter_without_radiance_emits_one_as_in_mitsuba(tmp_path):
    """Mitsuba 3's area emitter defaults its radiance to 1, as probvis's point and spot lights did; it was refused
    (sweep 42)."""
    def scene(emitter):
        return probvis.load_scene(write_scene(tmp_path / "a.xml", sensor() + "<shape type='rectangle'>"
                                              f"{emitter}</shape>"))
    implicit = scene("<emitter type='area'/>")
    explicit = scene("<emitter type='area'><rgb name='radiance' value='1'/></emitter>")
    np.testing.assert_array_equal(implicit.emitter_radiance, explicit.emitter_radiance)
    np.testing.assert_array_equal(implicit.emitter_radiance, [[1.0, 1.0, 1.0]])


def test_a_spot_light_stretched_warns_that_its_cone_stays_round(tmp_path):
    """Mitsuba 3's spot light tests directions in its own frame, so a non-uniform scale makes the cone elliptical;
    probvis's cone is round about its axis: the same image with and without the scale, so it warns (it was
    silent, sweep 42). A uniform scale changes nothing in either and does not warn."""
    def spot(transform):
        return write_scene(tmp_path / "spot.xml", sensor(sr=1) + "<shape type='rectangle'/><emitter type='spot'>"
                           f"<transform name='to_world'>{transform}<lookat origin='0, 0, 2' target='0, 0, 0'/>"
                           "</transform></emitter>")
    with pytest.warns(UserWarning, match=r"spot.xml:\d+: the spot light's to_world has a non-uniform "
                                         "scale or a shear, which makes its cone elliptical in Mitsuba 3"):
        probvis.load_scene(spot("<scale x='3' y='1' z='1'/>"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        probvis.load_scene(spot("<scale value='2'/>"))


def test_a_reference_to_a_bsdf_or_texture_defined_below_reads_it_as_mitsuba_does(tmp_path):
    """Mitsuba resolves a <ref> to a top-level object defined further down the file; so does probvis (it reads
    the object ahead, once): the image is the one of the file in the usual order."""
    head = sensor(origin="0, -3, 1.5", target="0, 0, 0.3", up="0, 0, 1", fov=40, spp="4", w=16, h=16) + \
        '<emitter type="point"><point name="position" x="0.5" y="-0.5" z="2"/>' \
        '<rgb name="intensity" value="5"/></emitter>'
    tex = ('<texture type="checkerboard" id="t"><rgb name="color0" value="0.2"/>'
           '<rgb name="color1" value="0.8"/></texture>')
    bsdf = '<bsdf type="twosided" id="m"><bsdf type="diffuse"><ref name="reflectance" id="t"/></bsdf></bsdf>'
    shape = '<shape type="rectangle"><transform name="to_world"><scale value="2"/></transform><ref id="m"/></shape>'
    usual = probvis.load_scene(write_scene(tmp_path / "a.xml", head + tex + bsdf + shape))
    below = write_scene(tmp_path / "b.xml", head + shape + bsdf + tex)
    ahead = probvis.load_scene(below)
    np.testing.assert_array_equal(probvis.render(ahead, seed=1).image, probvis.render(usual, seed=1).image)
    assert len(ahead.reflectance) == len(usual.reflectance)  # each read once
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    assert len(mi.load_file(str(below)).shapes()) == 1  # a scene Mitsuba loads


def test_a_mitsuba_0_6_scene_s_error_names_its_format(tmp_path):
    """A 0.6 scene's camelCase parameter was only 'unsupported parameter sampleCount'."""
    path = write_scene(tmp_path / "old.xml", sensor() + LIGHT)
    text = path.read_text().replace('version="3.0.0"', 'version="0.6.0"').replace("sample_count", "sampleCount")
    assert "sampleCount" in text
    path.write_text(text)
    with pytest.raises(ProbvisError, match=r"unsupported parameter 'sampleCount'.*Mitsuba 0.6.0's format; probvis "
                                           r"reads Mitsuba 3's, whose names are snake_case"):
        probvis.load_scene(path)
    path.write_text(text.replace("sampleCount", "sample_count").replace('name="width" value="16"',
                                                                         'name="width" value="-16"'))
    assert 'value="-16"' in path.read_text()  # an error that is no matter of the format: no hint
    with pytest.raises(ProbvisError) as caught:
        probvis.load_scene(path)
    assert "Mitsuba 0.6.0's format" not in str(caught.value)


def test_an_include_that_names_a_folder_says_so(tmp_path):
    (tmp_path / "inc.xml").mkdir()
    path = write_scene(tmp_path / "s.xml", sensor() + "<include filename='inc.xml'/>" + LIGHT)
    with pytest.raises(ProbvisError, match=r"s.xml:\d+: <include>: included file 'inc.xml' is a folder"):
        probvis.load_scene(path)


def test_an_include_of_a_device_or_pipe_says_it_is_not_a_regular_file(tmp_path):
    """/dev/null or a FIFO exists but is no scene file: "not found" misled."""
    fifo = tmp_path / "pipe.xml"
    os.mkfifo(fifo)
    for name in ("/dev/null", "pipe.xml"):
        path = write_scene(tmp_path / "s.xml", sensor() + f"<include filename='{name}'/>" + LIGHT)
        with pytest.raises(ProbvisError, match=r"s.xml:\d+: <include>: included file '.*': .* is not a regular file"):
            probvis.load_scene(path)


@pytest.mark.parametrize("root", ["<scene>", "<bsdf type='diffuse' id='m'>"])
def test_a_file_whose_root_has_no_version_is_refused_as_in_mitsuba(tmp_path, root):
    """Mitsuba 3.9 refuses a scene file, or an included one, whose root element has no version attribute."""
    if root == "<scene>":
        path = tmp_path / "s.xml"
        path.write_text("<scene>\n" + sensor() + LIGHT + "</scene>\n")
    else:
        (tmp_path / "m.xml").write_text(root + "</bsdf>\n")
        path = write_scene(tmp_path / "s.xml", sensor() + "<include filename='m.xml'/>" + LIGHT)
    where = "s.xml" if root == "<scene>" else "m.xml"
    with pytest.raises(ProbvisError, match=rf"{where}:1: <\w+>: missing version attribute"):
        probvis.load_scene(path)
    if importlib.util.find_spec("mitsuba") is not None:
        import mitsuba as mi

        mi.set_variant("scalar_rgb")
        with pytest.raises(Exception, match="missing version attribute"):
            mi.load_file(str(path))


@pytest.mark.parametrize("encoding, declared", [("utf-8", "bogus-enc"), ("utf-8", "rot13"), ("utf-8", "utf-32"),
                                                ("utf-32", "utf-32"), ("utf-16", "utf-16"), ("utf-8-sig", None),
                                                ("latin-1", "latin-1"), ("utf-16-le", None)])
def test_a_scene_reads_in_the_encoding_its_first_bytes_or_declaration_give(tmp_path, encoding, declared):
    """UTF-16/32 by their first bytes, a declared encoding Python knows, else UTF-8 (a declaration naming an
    unknown or non-text codec was a LookupError traceback, UTF-32 'invalid token'): the same scene as UTF-8's."""
    head = f'<?xml version="1.0" encoding="{declared}"?>\n' if declared else '<?xml version="1.0"?>\n'
    body = '<scene version="3.0.0">\n<!-- café -->\n' + sensor() + LIGHT + "</scene>\n"
    plain = tmp_path / "plain.xml"
    plain.write_text(body, encoding="utf-8")
    path = tmp_path / "s.xml"
    path.write_bytes((head + body).encode(encoding))
    assert np.array_equal(probvis.render(path, spp=1).image, probvis.render(plain, spp=1).image)


@pytest.mark.parametrize("declaration", ['<?xml version="1.0"\n  encoding="latin-1"?>',
                                         '<?xml version="1.0"\r\n encoding\r\n=\r\n"latin-1"?>',
                                         '<?xml version="1.0"' + " " * 1100 + 'encoding="bogus"?>',
                                         '<?xml version="1.0" encoding="utf\x008"?>',
                                         '<?xml version="1.0" encoding="unicode_escape"?>'])
def test_an_encoding_declaration_of_any_length_keeps_the_lines_and_reads_no_escapes(tmp_path, declaration):
    """A declaration over several lines kept the later lines' numbers only if it is blanked, not cut; one longer
    than 1 KiB or naming an escape codec or a NUL was read by the XML reader itself (a traceback)."""
    lines = declaration.count("\n")
    path = tmp_path / "s.xml"
    path.write_bytes((declaration + '\n<scene version="3.0.0">\n<!-- caf\\x41 -->\n<bogus/>\n</scene>\n')
                     .encode("latin-1"))
    with pytest.raises(ProbvisError, match=rf"s.xml:{lines + 4}: <bogus>: unsupported element"):
        probvis.load_scene(path)


def test_an_escape_codec_declared_is_not_applied(tmp_path):
    """unicode_escape or UTF-7 would read a backslash or '+' in a file name or id as an escape."""
    body = sensor() + LIGHT + "<shape type='sphere' id='a\\x41+AGE-'/>"
    for codec in ("unicode_escape", "raw_unicode_escape", "utf-7"):
        path = write_scene(tmp_path / "s.xml", body)
        path.write_text(f'<?xml version="1.0" encoding="{codec}"?>' + path.read_text().split("?>", 1)[1])
        assert "a\\x41+AGE-" in [shape.name for shape in probvis.load_scene(path).shapes]


def test_a_scene_in_no_encoding_that_reads_it_names_its_line(tmp_path):
    path = tmp_path / "s.xml"
    path.write_bytes(b'<?xml version="1.0" encoding="bogus"?>\n<scene version="3.0.0">\n<!-- caf\xe9 -->\n</scene>\n')
    with pytest.raises(ProbvisError, match=r"s.xml:3: not UTF-8 text, and its declared encoding 'bogus' is unknown"):
        probvis.load_scene(path)
    path.write_bytes(b'\xff\xfe\x00\x00<\x00\x00\x00\xff\xff\xff\xff')
    with pytest.raises(ProbvisError, match=r"s.xml: not UTF-32 text as its first bytes say"):
        probvis.load_scene(path)


def test_a_shape_s_reference_to_an_emitter_says_where_a_shape_s_emitter_goes(tmp_path):
    """"is a <emitter>, not a bsdf" suggested that only a bsdf could stand in a shape."""
    path = write_scene(tmp_path / "s.xml", sensor() + LIGHT + '<emitter type="point" id="pl"><point name="position" '
                       'value="0, 0, 2"/></emitter><shape type="sphere"><ref id="pl"/></shape>')
    with pytest.raises(ProbvisError, match=re.escape("<ref>: id 'pl' is an <emitter>: a shape's emitter is written "
                                                     'inside the shape (<emitter type="area">)')):
        probvis.load_scene(path)
