"""Cameras, films and filters against Mitsuba 3 (scalar_rgb): ray for ray where the sample maps agree, image
for image (within Mitsuba's own noise, image means within 1%) where only the distributions do."""
import re
import warnings

import numpy as np
import pytest

import probvis
from probvis import ProbvisError
from probvis.camera import STREAM_CAMERA, camera_params, camera_rays
from probvis.rng import make_key, uniform
from tests.conftest import assert_matches_mitsuba, mitsuba_image, relmse, write_scene

mi = pytest.importorskip("mitsuba")
mi.set_variant("scalar_rgb")

LOOK = '<transform name="to_world"><lookat origin="0.3, -2.6, 1.6" target="0, 0, 0.3" up="0, 0, 1"/></transform>'
SCENE = """
    <bsdf type="diffuse" id="floor"><rgb name="reflectance" value="0.7, 0.6, 0.5"/></bsdf>
    <shape type="rectangle"><transform name="to_world"><scale value="2"/></transform><ref id="floor"/></shape>
    <shape type="cube"><transform name="to_world"><scale x="0.25" y="0.4" z="0.3"/>
        <rotate z="1" angle="30"/><translate x="-0.3" y="0.2" z="0.3"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.6, 0.3"/></bsdf></shape>
    <shape type="rectangle"><transform name="to_world"><scale x="0.4" y="0.25"/><rotate x="1" angle="160"/>
        <translate x="0.2" y="0.3" z="1.6"/></transform>
        <emitter type="area"><rgb name="radiance" value="12, 10, 8"/></emitter></shape>"""


def sensor_xml(kind="perspective", params="", film="", rfilter='<rfilter type="box"/>', w=40, h=32, spp="$spp"):
    return f"""<sensor type="{kind}">{params}{LOOK}
        <sampler type="independent"><integer name="sample_count" value="{spp}"/></sampler>
        <film type="hdrfilm"><integer name="width" value="{w}"/><integer name="height" value="{h}"/>{film}
            {rfilter}</film></sensor>
    <integrator type="direct"><integer name="emitter_samples" value="4"/><integer name="bsdf_samples" value="0"/>
    </integrator>"""


def scene_file(tmp_path, sensor):
    return write_scene(tmp_path / "s.xml", sensor + SCENE, '<default name="spp" value="16"/>')


@pytest.mark.parametrize("params, film", [
    ('<float name="fov" value="45"/>', ""),
    ('<float name="fov" value="30"/><string name="fov_axis" value="y"/>', ""),
    ('<float name="fov" value="50"/><string name="fov_axis" value="diagonal"/>', ""),
    ('<float name="fov" value="40"/><string name="fov_axis" value="smaller"/>', ""),
    ('<float name="fov" value="40"/><string name="fov_axis" value="larger"/>', ""),
    ("", ""),  # Mitsuba's default: a 50 mm lens
    ('<string name="focal_length" value="28mm"/>', ""),
    ('<float name="fov" value="45"/><float name="principal_point_offset_x" value="0.1"/>'
     '<float name="principal_point_offset_y" value="-0.05"/>', ""),
    ('<float name="fov" value="45"/>', '<integer name="crop_offset_x" value="10"/><integer name="crop_offset_y" '
     'value="4"/><integer name="crop_width" value="17"/><integer name="crop_height" value="9"/>'),
])
def test_camera_rays_are_mitsuba_s(tmp_path, params, film):
    """Our kernel's rays against Mitsuba's `sample_ray` at the same film positions (the pixel jitter drawn
    from our random numbers), for every field-of-view convention, the principal point and a crop window."""
    assert_rays_match(scene_file(tmp_path, sensor_xml(params=params, film=film)))


def test_a_film_larger_than_probvis_renders_gives_its_crop_window_s_rays(tmp_path):
    """A 100000 x 80000 film with a 16 x 12 crop window is rendered as Mitsuba renders it (probvis refused any film
    side above 32768, though only the crop is rendered); uncropped, it is refused in one line."""
    crop = ('<integer name="crop_offset_x" value="49990"/><integer name="crop_offset_y" value="39994"/>'
            '<integer name="crop_width" value="16"/><integer name="crop_height" value="12"/>')
    big = sensor_xml(params='<float name="fov" value="45"/>', film=crop, w=100000, h=80000)
    assert_rays_match(scene_file(tmp_path, big))
    with pytest.raises(ProbvisError, match=re.escape("<film>: film size 100000x80000 is out of range (1 to 32768): "
                                                     "render it in crop windows")):
        probvis.load_scene(scene_file(tmp_path, big.replace(crop, "")))


def assert_rays_match(path):
    ours = probvis.load_scene(path)
    cam = ours.camera
    theirs = mi.load_file(str(path), spp=1).sensors()[0]
    org, dirs, _, _, _, _ = camera_rays(camera_params(cam), 1, 3, np.arange(cam.width * cam.height))
    for pix in range(0, cam.width * cam.height, 7):
        key = np.uint64(make_key(3, STREAM_CAMERA, pix))  # numba hands the uint64 back as a Python int
        pos = mi.Point2f(((pix % cam.width) + uniform(key, 0)) / cam.width,
                         ((pix // cam.width) + uniform(key, 1)) / cam.height)
        ray, _ = theirs.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
        np.testing.assert_allclose(dirs[pix], np.array(ray.d), atol=2e-6)


def test_thin_lens_rays_meet_mitsuba_s_in_the_focal_plane(tmp_path):
    params = '<float name="fov" value="45"/><float name="aperture_radius" value="0.2"/>' \
             '<float name="focus_distance" value="2.5"/>'
    path = scene_file(tmp_path, sensor_xml("thinlens", params))
    cam = probvis.load_scene(path).camera
    theirs = mi.load_file(str(path), spp=1).sensors()[0]
    org, dirs, _, _, _, _ = camera_rays(camera_params(cam), 1, 5, np.arange(cam.width * cam.height))
    m = cam.to_world
    eye, forward = m[:3, 3], m[:3, 2]
    radii = []
    for pix in range(0, cam.width * cam.height, 5):
        key = np.uint64(make_key(5, STREAM_CAMERA, pix))
        pos = mi.Point2f(((pix % cam.width) + uniform(key, 0)) / cam.width,
                         ((pix // cam.width) + uniform(key, 1)) / cam.height)
        ray, _ = theirs.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))  # through the lens centre
        o, d = np.array(ray.o), np.array(ray.d)
        focus_theirs = o + d * ((2.5 - (o - eye) @ forward) / (d @ forward))
        focus_ours = org[pix] + dirs[pix] * ((2.5 - (org[pix] - eye) @ forward) / (dirs[pix] @ forward))
        np.testing.assert_allclose(focus_ours, focus_theirs, atol=1e-5)
        radii.append(np.linalg.norm(org[pix] - eye))
    assert max(radii) <= 0.2 + 1e-9 and min(radii) < 0.1 < max(radii)  # spread over the aperture


def test_a_negative_aperture_is_the_same_lens_as_in_mitsuba(tmp_path):
    """Mitsuba scales its unit-disk sample by aperture_radius as given, so -0.2 is the disk of 0.2: same image."""
    def lens(radius):
        return (f'<float name="fov" value="45"/><float name="aperture_radius" value="{radius}"/>'
                '<float name="focus_distance" value="2.5"/>')
    images = [probvis.render(write_scene(tmp_path / f"{k}.xml", sensor_xml("thinlens", lens(r)) + SCENE,
                                         '<default name="spp" value="4"/>'), seed=2).image
              for k, r in (("pos", 0.2), ("neg", -0.2))]
    np.testing.assert_array_equal(images[0], images[1])
    theirs = mi.load_file(str(tmp_path / "neg.xml"), spp=4)  # Mitsuba takes it too
    assert theirs.sensors()[0] is not None


@pytest.mark.parametrize("kind, params, rfilter", [
    ("perspective", '<float name="fov" value="45"/>', '<rfilter type="box"/>'),
    ("thinlens", '<float name="fov" value="45"/><float name="aperture_radius" value="0.15"/>'
                 '<float name="focus_distance" value="2.0"/>', '<rfilter type="box"/>'),
    ("perspective", '<float name="fov" value="45"/><float name="principal_point_offset_x" value="0.1"/>',
     '<rfilter type="box"/>'),
])
def test_images_match_mitsuba(tmp_path, kind, params, rfilter):
    """Same sample distribution as Mitsuba: no more error than Mitsuba's own at equal settings."""
    assert_matches_mitsuba(scene_file(tmp_path, sensor_xml(kind, params, rfilter=rfilter)))


def edge_scene(tmp_path, rfilter):
    """An emitter seen directly, its slanted edges sharp against black: what a filter changes most."""
    return write_scene(tmp_path / "edge.xml", f"""<sensor type="perspective"><float name="fov" value="45"/>
        <transform name="to_world"><lookat origin="0, 0, 3" target="0, 0, 0" up="0, 1, 0"/></transform>
        <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
        <film type="hdrfilm"><integer name="width" value="48"/><integer name="height" value="40"/>{rfilter}</film>
        </sensor><integrator type="direct"><integer name="bsdf_samples" value="0"/></integrator>
        <shape type="rectangle"><transform name="to_world"><rotate z="1" angle="17"/><scale value="0.7"/></transform>
            <emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>""",
        '<default name="spp" value="16"/>')


@pytest.fixture(scope="module")
def box_filtered(tmp_path_factory):
    """The edge scene's image through a box filter, which the filtered images must be told apart from."""
    return probvis.render(edge_scene(tmp_path_factory.mktemp("box"), '<rfilter type="box"/>'), spp=1024, seed=1).image


@pytest.mark.parametrize("rfilter", ['<rfilter type="tent"/>', '<rfilter type="tent"><float name="radius" value="2"/>'
                                     '</rfilter>', '<rfilter type="gaussian"/>', ""])
def test_filtered_images_converge_to_mitsuba_s(tmp_path, rfilter, box_filtered):
    """With filter importance sampling (each sample in one pixel, drawn from the filter) the images converge to
    Mitsuba's splatted ones: our error against Mitsuba's reference is what our own noise and the reference's
    explain (measured from a second seed of each), and a box filter's is not (no rfilter: Mitsuba's default, a
    Gaussian; the box's error is 45-150x what is explained at these sample counts). The splatting film's
    comparisons at equal samples are in test_film.py."""
    path = edge_scene(tmp_path, rfilter)
    ref = mitsuba_image(path, 1024, seed=100)
    ref_noise = relmse(mitsuba_image(path, 1024, seed=7), ref) / 2
    a, b = (probvis.render(path, spp=2048, seed=s, filter_importance=True).image for s in (1, 2))
    explained = relmse(a, b) / 2 + ref_noise
    assert relmse(a, ref) < 2.5 * explained
    assert relmse(box_filtered, ref) > 10 * explained  # a box filter is told apart: the comparison bites


def test_path_integrator_renders_its_direct_component_with_one_warning(tmp_path):
    direct = scene_file(tmp_path, sensor_xml(params='<float name="fov" value="45"/>'))
    text = direct.read_text().replace(
        '<integrator type="direct"><integer name="emitter_samples" value="4"/><integer name="bsdf_samples" '
        'value="0"/>\n    </integrator>', '<integrator type="path"><integer name="max_depth" value="8"/></integrator>')
    path = tmp_path / "path.xml"
    path.write_text(text)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        a = probvis.render(path, spp=2, seed=3, defines={})
    assert len(caught) == 1 and "rendered as its direct-illumination component" in str(caught[0].message)
    b = probvis.render(direct, spp=2, shadow_rays=1, seed=3)
    np.testing.assert_array_equal(a.image, b.image)


@pytest.mark.parametrize("fov", ['<float name="fov" value="40"/><string name="fov_axis" value="{}"/>', ""])
@pytest.mark.parametrize("axis", ["x", "y", "diagonal", "smaller", "larger"])
def test_another_resolution_keeps_the_declared_field_of_view_along_its_axis(tmp_path, fov, axis):
    """`resolution=` (and a study's) kept the horizontal field of view computed at the declared film's shape, so
    a view declared 40 degrees tall, or by a focal length (the film's diagonal), changed with the new shape: the
    camera is now the one the scene declares at that size."""
    def scene(w, h):
        body = (f'<sensor type="perspective">{fov.format(axis)}<transform name="to_world"><lookat origin="0, 0, 4" '
                f'target="0, 0, 0" up="0, 1, 0"/></transform><film type="hdrfilm"><integer name="width" value="{w}"/>'
                f'<integer name="height" value="{h}"/></film></sensor><shape type="rectangle"/>'
                '<emitter type="point"><point name="position" x="0" y="0" z="2"/></emitter>')
        return probvis.load_scene(write_scene(tmp_path / f"s{w}x{h}.xml", body))

    resized = scene(16, 32).with_resolution(32, 16).camera
    declared = scene(32, 16).camera
    assert (resized.width, resized.height) == (32, 16)
    assert resized.fov_x == pytest.approx(declared.fov_x, rel=1e-12)
