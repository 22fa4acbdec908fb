"""Direct illumination against closed forms, determinism, and the stats contract."""
import dataclasses
import re
import warnings

import numba
import numpy as np
import pytest

import probvis
from probvis import ProbvisError
from probvis.visibility import RenderPath
from probvis.visibility.exact import ExactVisibility
from tests.conftest import sensor, write_scene


def corner_form_factor(x, y):
    """Form factor from a point to a parallel rectangle [0, x] x [0, y] at unit height above its corner."""
    a, b = np.sqrt(1 + x * x), np.sqrt(1 + y * y)
    return (x / a * np.arctan(y / a) + y / b * np.arctan(x / b)) / (2 * np.pi)


def light_over_floor(tmp_path, h=1.0, a=0.5, b=0.3, radiance=5.0, extra="", cam_z=None, spp=4, sr=4):
    cam_z = h / 2 if cam_z is None else cam_z
    body = sensor(origin=f"0, 0, {cam_z}", target="0, 0, 0", fov=0.5, spp=spp, sr=sr, w=32, h=32) + f"""
    <shape type="rectangle"><transform name="to_world"><scale value="10"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.8, 0.5, 0.25"/></bsdf></shape>
    <shape type="rectangle">
        <transform name="to_world"><scale x="{a}" y="{b}"/><rotate x="1" angle="180"/><translate z="{h}"/></transform>
        <emitter type="area"><rgb name="radiance" value="{radiance}"/></emitter></shape>
    {extra}"""
    return write_scene(tmp_path / "s.xml", body)


def test_irradiance_from_an_unoccluded_rectangle(tmp_path):
    """L_o = albedo * L_e * F, F = 4 corner form factors for the point under the centre of the light."""
    h, a, b, le = 1.0, 0.5, 0.3, 5.0
    r = probvis.render(light_over_floor(tmp_path, h, a, b, le), seed=3)
    expected = np.array([0.8, 0.5, 0.25]) * le * 4 * corner_form_factor(a / h, b / h)
    px = r.image.reshape(-1, 3)
    se = px.std(axis=0) / np.sqrt(len(px))
    assert np.all(se > 0)
    assert np.all(np.abs(px.mean(axis=0) - expected) < 4 * se + 1e-4 * expected)


def test_point_in_full_shadow_is_black(tmp_path):
    blocker = """<shape type="rectangle"><transform name="to_world"><scale value="3"/><translate z="0.6"/>
        </transform><bsdf type="twosided"><bsdf type="diffuse"/></bsdf></shape>"""
    with pytest.warns(UserWarning, match="the image is black"):
        r = probvis.render(light_over_floor(tmp_path, extra=blocker, cam_z=0.3))
    assert np.all(r.image == 0.0)
    assert r.stats["shadow_rays"] > 0 and r.stats["intersection_tests"]["shadow"]["triangle"] > 0


def test_emitter_seen_directly_front_and_back(tmp_path):
    light = """<shape type="rectangle"><transform name="to_world"><scale value="2"/></transform>
        <emitter type="area"><rgb name="radiance" value="1.5, 2, 3"/></emitter></shape>"""
    front = probvis.render(write_scene(tmp_path / "f.xml", sensor(origin="0, 0, 1", fov=30) + light))
    np.testing.assert_array_equal(front.image, np.broadcast_to([1.5, 2.0, 3.0], front.image.shape))
    with pytest.warns(UserWarning, match="the image is black"):
        back = probvis.render(write_scene(tmp_path / "b.xml", sensor(origin="0, 0, -1", fov=30) + light))
    assert np.all(back.image == 0.0)


def test_one_sided_floor_is_black_from_below(tmp_path):
    with pytest.warns(UserWarning, match="the image is black"):
        r = probvis.render(light_over_floor(tmp_path, cam_z=-1.0))
    assert np.all(r.image == 0.0) and r.stats["shadow_rays"] == 0


def test_same_image_whatever_the_thread_count_and_seed_matters():
    scene = probvis.load_scene("cornell-box", res=24, spp=2, shadow_rays=3)
    before = numba.get_num_threads()
    try:
        one = probvis.render(scene, threads=1, seed=5)
        two = probvis.render(scene, threads=numba.config.NUMBA_NUM_THREADS, seed=5)
    finally:
        numba.set_num_threads(before)
    np.testing.assert_array_equal(one.image, two.image)
    np.testing.assert_array_equal(one.aovs["triangle_tests"], two.aovs["triangle_tests"])
    other = probvis.render(scene, seed=6)
    assert not np.array_equal(one.image, other.image)


class StagedExact(ExactVisibility):
    """Exact visibility through the staged path (slots, compaction, `evaluate`, the samples' radiance)."""

    def render_path(self):
        return RenderPath.STAGED


@pytest.mark.parametrize("two_lights, shadow_rays", [(False, 3), (True, 70)])
def test_fused_exact_path_matches_the_staged_path(tmp_path, two_lights, shadow_rays):
    """The integrator's fused kernel for exact visibility gives the staged path's image, moments, per-pixel
    counts and totals bit for bit: one light and short packets, and two lights (an emitter choice per sample)
    with 70 shadow rays, more than one packet per shading point."""
    if two_lights:
        body = sensor(origin="0, 0, 0.9", target="0, 0, 0", fov=60, spp=3, sr=shadow_rays) + """
            <shape type="rectangle"><transform name="to_world"><scale value="2"/></transform>
                <bsdf type="diffuse"/></shape>
            <shape type="cube"><transform name="to_world"><scale value="0.15"/><translate z="0.4"/></transform>
                <bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.6, 0.3"/></bsdf></shape>
            <shape type="rectangle"><transform name="to_world"><scale value="0.4"/><rotate x="1" angle="180"/>
                <translate z="1.0"/></transform><emitter type="area"><rgb name="radiance" value="4"/></emitter></shape>
            <shape type="rectangle"><transform name="to_world"><scale value="0.2"/><rotate x="1" angle="150"/>
                <translate x="0.6" z="0.8"/></transform>
                <emitter type="area"><rgb name="radiance" value="9, 3, 1"/></emitter></shape>"""
        scene = probvis.load_scene(write_scene(tmp_path / "two.xml", body))
    else:
        scene = probvis.load_scene("cornell-box", res=24, spp=4, shadow_rays=shadow_rays)
    fused = probvis.render(scene, seed=11)
    staged = probvis.render(scene, seed=11, visibility=StagedExact())
    np.testing.assert_array_equal(fused.image, staged.image)
    for name in ("triangle_tests", "node_tests", "second_moment"):
        np.testing.assert_array_equal(fused.aovs[name], staged.aovs[name])
    for key in ("shadow_rays", "camera_hits", "intersection_tests", "negative_estimates"):
        assert fused.stats[key] == staged.stats[key]
    assert fused.stats["shadow_rays"] > 0 and fused.stats["intersection_tests"]["shadow"]["triangle"] > 0
    if two_lights:
        assert fused.stats["emitters"] == 2  # and some shading point has more than 64 segments:
        assert fused.stats["shadow_rays"] > 64 * fused.stats["camera_hits"]


def test_stats_and_test_count_image_add_up():
    r = probvis.render("quad-shadow", spp=2, shadow_rays=2, resolution=(12, 10))
    s = r.stats
    assert r.image.shape == (10, 12, 3)
    for key in ("total", "load", "bvh", "prepare", "compile", "render"):
        assert s["seconds"][key] >= 0
    assert s["camera_rays"] == 12 * 10 * 2
    it = s["intersection_tests"]
    assert it["triangle"] == r.aovs["triangle_tests"].sum() > 0
    assert it["node"] == r.aovs["node_tests"].sum() > 0
    assert it["triangle"] == it["camera"]["triangle"] + it["shadow"]["triangle"]
    assert 0 < s["shadow_rays"] <= s["camera_rays"] * 2
    assert it["shadow"]["triangle_per_ray"] == pytest.approx(it["shadow"]["triangle"] / s["shadow_rays"])
    assert it["shadow"]["node_per_ray"] == pytest.approx(it["shadow"]["node"] / s["shadow_rays"])
    assert s["visibility"]["name"] == "exact" and s["seed"] == 0 and s["spp"] == 2


@pytest.mark.parametrize("kwargs, message", [
    ({"spp": 0}, "spp must be"), ({"shadow_rays": -1}, "shadow_rays must be"),
    ({"resolution": (0, 4)}, "width must be"), ({"visibility": "magic"}, "unknown visibility"),
    ({"threads": 999}, "threads must be"),
    ({"spp": "4"}, r"spp must be a whole number, got '4' \(a str\)"), ({"spp": 2.5}, "spp must be a whole number"),
    ({"resolution": 8}, r"resolution must be \(width, height\)"),
    ({"resolution": (8, 8, 8)}, r"resolution must be \(width, height\)"),
    ({"defines": ["res=8"]}, "defines must be a dict"), ({"visibility_options": ["x"]}, "visibility_options must be"),
    ({"settings": "fast"}, "settings must be a RenderSettings"),
    ({"filter_importance": "yes"}, "filter_importance must be True or False"),
    ({"visibility_options": {1: 2}}, "visibility_options must be a dict with names"),
    ({"strict": "no"}, "strict must be True or False, got 'no'"),
    ({"clamp_negative": "no"}, "clamp_negative must be True or False"),
])
def test_bad_render_settings(kwargs, message):
    with pytest.raises(ProbvisError, match=message):
        probvis.render("quad-shadow", **kwargs)


def test_a_numpy_resolution_is_two_whole_numbers():
    r = probvis.render("quad-shadow", spp=1, shadow_rays=1, resolution=np.array([8, 6]))
    assert r.image.shape == (6, 8, 3)


@pytest.mark.parametrize("scene", [None, 42, 1.5, ["quad-shadow"]])
def test_a_scene_of_the_wrong_type_is_named(scene):
    with pytest.raises(ProbvisError, match="scene must be a Scene, a scene file path or a built-in name"):
        probvis.render(scene)


def test_shared_scenes_within_noise_floor(shared):
    """relMSE against the Mitsuba references at 128 px, 16 spp x 16 shadow rays, two seeds averaged, is
    within 1.5x the floor of independent Mitsuba renders (floors.json)."""
    import json

    from probvis.io import read_exr
    from tests.conftest import relmse

    floors = json.loads((shared / "reference" / "floors.json").read_text())
    for name in ("cornell-bunny", "city", "leaves"):
        ref = read_exr(shared / "reference" / f"{name}-128.exr").astype(np.float64)
        err = np.mean([relmse(probvis.render(shared / "scenes" / f"{name}.xml", spp=16, shadow_rays=16,
                                             seed=s, defines={"res": 128}).image, ref) for s in (1, 2)])
        assert err <= 1.5 * np.mean(floors[name]["relmse_16spp_16sr"]), name


@pytest.mark.parametrize("args, kwargs, message", [
    ((None,), {}, "path must be a scene file path or a built-in name, got NoneType"),
    ((42,), {}, "path must be a scene file path or a built-in name, got int"),
    (("\n  <?xml version='1.0'?>\n<scene version='3.0.0'>\n" + " " * 5000 + "</scene>",), {},
     "the scene is given as XML text (5,057 characters, '<?xml version='1.0'?> <scene v...'): probvis reads scene "
     "files: save the text to a file and give its path"),  # the whole document was quoted back
    (("quad-shadow", "yes"), {}, "strict must be True or False, got 'yes'"),
    (("quad-shadow",), {"res": True}, "parameter res must be an integer, got 'True'"),
    (("quad-shadow",), {"res": 8.5}, "parameter res must be an integer"),
    (("quad-shadow",), {"spp": np.float32(2.5)}, "parameter spp must be an integer, got '2.5'"),  # was 2
    (("quad-shadow",), {"res": np.longdouble(8.5)}, "parameter res must be an integer"),
])
def test_load_scene_names_arguments_of_the_wrong_type(args, kwargs, message):
    with pytest.raises(ProbvisError, match=re.escape(message)):
        probvis.load_scene(*args, **kwargs)


@pytest.mark.parametrize("kwargs, message", [
    ({"seed": np.timedelta64(2, "s")}, "seed must be a whole number, got "),
    ({"threads": np.timedelta64(1, "s")}, "threads must be a whole number"),
    ({"resolution": (np.timedelta64(8), np.timedelta64(8))}, "resolution must be (width, height), two whole"),
    ({"visibility": "occlusion-map", "visibility_options": {"photons": np.timedelta64(1000)}}, "photons"),
])
def test_a_numpy_time_span_is_no_number(kwargs, message):
    """NumPy counts np.timedelta64 as an integer (and so does `numbers`): it passed the checks, then int() of it
    failed inside, a TypeError or a ctypes ArgumentError from Numba."""
    with pytest.raises(ProbvisError, match=re.escape(message)):
        probvis.render("quad-shadow", spp=1, shadow_rays=1, **kwargs)
    scene = probvis.load_scene("quad-shadow", res=8)
    with pytest.raises(ProbvisError, match="camera.width must be a whole number"):
        scene.with_resolution(np.timedelta64(8), 8)


def test_settings_the_api_would_drop_are_refused():
    """`strict` with a loaded scene did nothing (it applies when a file is read), `defines` with res beside
    `resolution` lost to it, and `with_resolution((w, h))` blamed an internal field (sweep 42)."""
    scene = probvis.load_scene("quad-shadow", res=8)
    with pytest.raises(ProbvisError, match=r"strict applies when a scene is loaded: give it to load_scene"):
        probvis.render(scene, spp=1, shadow_rays=1, strict=True)
    with pytest.raises(ProbvisError, match=r"resolution= and the scene parameter res \(defines\) both set"):
        probvis.render("quad-shadow", spp=1, shadow_rays=1, defines={"res": 8}, resolution=(16, 16))
    with pytest.raises(ProbvisError, match=r"with_resolution takes the width and height as two arguments, got "
                                           r"\(16, 16\): with_resolution\(w, h\)"):
        scene.with_resolution((16, 16))
    assert probvis.render(scene, spp=1, shadow_rays=1, resolution=(16, 12)).image.shape == (12, 16, 3)


def test_numpy_values_are_taken_alike_everywhere():
    """A NumPy bool is a flag and a whole NumPy number a count wherever the API takes one (it was a flag for
    `strict` but not for `filter_importance` or an estimator's switch; a long double was no number to an
    estimator's option); the same image as with Python's values."""
    plain = probvis.render("quad-shadow", spp=2, shadow_rays=1, resolution=(8, 8), filter_importance=True,
                           visibility="occlusion-map", visibility_options={"radius": 0.1, "cache": False})
    numpy = probvis.render("quad-shadow", spp=np.float16(2), shadow_rays=np.uint8(1), resolution=(8.0, np.int8(8)),
                           filter_importance=np.True_, visibility="occlusion-map",
                           visibility_options={"radius": np.longdouble(0.1), "cache": np.False_})
    np.testing.assert_array_equal(plain.image, numpy.image)
    for kwargs, message in (({"spp": 2.5}, "spp must be a whole number, got 2.5"),
                            ({"resolution": (8.5, 8)}, "resolution must be (width, height), two whole numbers")):
        with pytest.raises(ProbvisError, match=re.escape(message)):
            probvis.render("quad-shadow", shadow_rays=1, **kwargs)


def test_any_path_like_object_names_a_scene(tmp_path):
    """A `PurePosixPath` or a class with `__fspath__` was refused ('got P') where `Path` was taken; bytes stay
    refused."""
    from pathlib import PurePosixPath

    path = write_scene(tmp_path / "s.xml", sensor(spp=1, sr=1, w=8, h=8) + '<shape type="rectangle"/>'
                       '<emitter type="point"><point name="position" x="0" y="0" z="1"/></emitter>')

    class Named:
        def __fspath__(self):
            return str(path)

    images = [probvis.render(s).image for s in (path, PurePosixPath(path), Named())]
    np.testing.assert_array_equal(images[0], images[1])
    np.testing.assert_array_equal(images[0], images[2])
    with pytest.raises(ProbvisError, match="scene must be a Scene, a scene file path or a built-in name, got bytes"):
        probvis.render(b"quad-shadow")


def test_a_misspelt_or_missing_argument_is_named_with_the_nearest(tmp_path):
    """Python's TypeError ('got an unexpected keyword argument') was all a misspelt keyword got; `load_scene(path=)`
    said a required argument was missing though it was given."""
    from probvis.experiments import experiment, quick_experiment

    for call, message in ((lambda: probvis.render("quad-shadow", shadowrays=4), "render(): got an unexpected keyword "
                           "argument 'shadowrays' (did you mean shadow_rays=?)"),
                          (lambda: probvis.render(), "render(): missing a required argument: 'scene'"),
                          (lambda: probvis.load_scene(path="quad-shadow"), "(path is given first, by position"),
                          (lambda: experiment(quick_experiment(), tmp_path / "r", worker=2),
                           "experiment(): got an unexpected keyword argument 'worker' (did you mean workers=?)")):
        with pytest.raises(ProbvisError, match=re.escape(message)):
            call()
    assert not (tmp_path / "r").exists()


def test_a_number_for_a_text_option_is_its_text():
    """`verify` takes auto, off or a probability: 0.5 in the API (or a TOML file) means what `--verify 0.5` does."""
    as_number = probvis.render("quad-shadow", spp=1, shadow_rays=2, resolution=(8, 8), visibility="occlusion-map",
                               visibility_options={"verify": 0.5})
    as_text = probvis.render("quad-shadow", spp=1, shadow_rays=2, resolution=(8, 8), visibility="occlusion-map",
                             visibility_options={"verify": "0.5"})
    np.testing.assert_array_equal(as_number.image, as_text.image)
    with pytest.raises(ProbvisError, match="verify expects string, got True"):
        probvis.render("quad-shadow", visibility="occlusion-map", visibility_options={"verify": True})


def test_a_scene_whose_camera_was_changed_is_checked_again():
    scene = probvis.load_scene("quad-shadow", res=8)
    scene.camera.width = -5
    with pytest.raises(ProbvisError, match="width must be a whole number from 1 to 32768, got -5"):
        probvis.render(scene, spp=1)


def test_a_file_named_like_a_built_in_scene_is_said(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "quad-shadow").write_text("garbage")
    with pytest.warns(UserWarning, match=r"'quad-shadow' names a built-in scene and a file here"):
        probvis.load_scene("quad-shadow", res=8)


def test_numpy_whole_numbers_are_taken_as_python_ints():
    """np.uint8 shadow rays overflowed the batch planner's arithmetic; np.int64 threads failed in threadpoolctl."""
    r = probvis.render("quad-shadow", spp=np.int16(2), shadow_rays=np.uint8(200), threads=np.int64(1),
                       seed=np.uint64(3), resolution=(4, 4))
    plain = probvis.render("quad-shadow", spp=2, shadow_rays=200, threads=1, seed=3, resolution=(4, 4))
    np.testing.assert_array_equal(r.image, plain.image)
    assert type(r.stats["spp"]) is int and type(r.stats["seed"]) is int


def test_more_shadow_rays_per_pixel_than_a_batch_can_interrupt_are_refused():
    with pytest.raises(ProbvisError, match="spp x shadow_rays = 1048576 x 65536 is more than the 67,108,864"):
        probvis.render("quad-shadow", spp=1 << 20, shadow_rays=1 << 16, resolution=(4, 4))


@pytest.mark.parametrize("change, message", [
    (lambda s: setattr(s, "defaults", "garbage"), "scene.defaults must be a RenderSettings, got str"),
    (lambda s: setattr(s, "camera", None), "scene.camera must be a Camera, got NoneType"),
    (lambda s: s.triangles.__setitem__((0, 0, 0), np.nan), "scene.triangles must be finite"),
    (lambda s: setattr(s, "triangles", s.triangles[:, :2]), "scene.triangles must be a 6 x 3 x 3 array of floats"),
    (lambda s: setattr(s, "triangles", s.triangles.astype(">f8")), "array of floats (32 or 64 bits) in the "
                                                                    "machine's byte order, got (6, 3, 3) >f8"),
    (lambda s: setattr(s, "triangles", s.triangles.astype(np.float16)), "byte order, got (6, 3, 3) float16"),
    (lambda s: setattr(s, "tri_material", s.tri_material.astype(">i8")), "scene.tri_material must be a 6 array of "
                                                                          "integers (not uint64) in the machine's"),
    (lambda s: setattr(s, "tri_material", s.tri_material.astype(np.uint64)),
     "integers (not uint64) in the machine's byte order, got (6,) uint64: use scene.tri_material.astype(np.int32)"),
    (lambda s: setattr(s, "tri_emitter", s.tri_emitter.astype(np.uint64)), "scene.tri_emitter must be a 6 array of"),
    (lambda s: setattr(s, "triangles", None), "scene.triangles must be a n x 3 x 3 array of floats (32 or 64 bits) "
                                              "in the machine's byte order, got NoneType"),
    (lambda s: setattr(s, "reflectance", 0.5), "scene.reflectance must be a n x 3 array of floats"),
    (lambda s: setattr(s, "triangles", s.triangles[:0]),
     "scene.vertex_normals has 6 rows where scene.triangles has 0: the arrays with a row per triangle change"),
    (lambda s: setattr(s, "twosided", s.twosided[:0]), "scene.twosided has 0 rows where scene.reflectance has"),
    (lambda s: setattr(s, "reflectance", s.reflectance * -5), "scene.reflectance must be within [0, 1]"),
    (lambda s: setattr(s, "tri_material", s.tri_material + 100), "scene.tri_material and scene.tri_emitter must"),
    (lambda s: setattr(s, "shapes", ["garbage"]), "scene.shapes must be a list of ShapeInfo"),
    (lambda s: setattr(s, "textures", ["garbage"]), "scene.textures must be a list of Texture"),
    (lambda s: setattr(s, "environment", "garbage"), "scene.environment must be an Environment or None, got str"),
    (lambda s: setattr(s, "material_texture", s.material_texture + 5), "scene.material_texture index scene.textures"),
    (lambda s: setattr(s, "vertex_normals", s.vertex_normals * np.nan), "scene.vertex_normals must be finite"),
    (lambda s: s.camera.to_world.__setitem__((0, 3), np.nan),
     "the camera's to_world must be a finite, invertible affine"),
    (lambda s: setattr(s.camera, "fov_x", "40"), "camera.fov_x must be a number, got '40'"),
    (lambda s: setattr(s.camera, "width", 8.0), "camera.width must be a whole number, got 8.0"),
    (lambda s: setattr(s, "inputs", None), "scene.inputs must be a tuple of the paths"),
    (lambda s: setattr(s, "source", object()), "scene.source must be a string, got object"),
    (lambda s: setattr(s.camera, "principal_y", np.nan), "camera.principal_y must be finite, got nan"),
    (lambda s: setattr(s.camera, "film_width", 10 ** 12), "film_width must be a whole number from 1 to 16777216"),
    (lambda s: setattr(s.camera, "width", 2 ** 70), "width must be a whole number from 1 to 32768, got 1180591620717"),
    (lambda s: setattr(s.camera, "fov_x", 2 ** 64), "field of view must be above 0 and at most"),
    (lambda s: setattr(s.camera, "principal_x", 10 ** 400), "camera.principal_x must be finite, got 1000"),
    (lambda s: setattr(s.camera, "filter_radius", 1e6), "camera.rfilter must be one of box, tent, gaussian"),
    (lambda s: setattr(s, "emitter_radiance", s.emitter_radiance * 1e300), "scene.emitter_radiance must be at most"),
    (lambda s: setattr(s, "vertex_normals", s.vertex_normals * 0.0), "scene.vertex_normals must not be zero"),
])
def test_a_scene_changed_after_loading_is_checked(change, message):
    """The API's Scene is a mutable record: a changed one was a TypeError, an AttributeError or a garbage image."""
    scene = probvis.load_scene("quad-shadow", res=8)
    scene.triangles = scene.triangles.copy()
    scene.camera = dataclasses.replace(scene.camera, to_world=scene.camera.to_world.copy())
    change(scene)
    with pytest.raises(ProbvisError, match=re.escape(message)):
        probvis.render(scene, spp=1, shadow_rays=1)


@pytest.mark.parametrize("emitter", [
    '<emitter type="directional"><vector name="direction" x="0" y="0" z="1"/></emitter>',  # shining away
    '<emitter type="point"><point name="position" x="0" y="0" z="-1"/></emitter>',  # behind the one-sided floor
    '<shape type="cube"><transform name="to_world"><scale value="0.2"/><translate z="1"/></transform></shape>'
    '<emitter type="point"><point name="position" x="0" y="0" z="1"/></emitter>',  # inside a closed cube
])
def test_a_black_image_is_warned_of(tmp_path, emitter):
    """No light reaching the camera rendered a black image without a word (exit 0 on the command line); the
    same scene lit from the front renders without the warning."""
    path = write_scene(tmp_path / "s.xml", sensor(spp=1, sr=1, w=8, h=8) + '<shape type="rectangle"/>' + emitter)
    with pytest.warns(UserWarning, match=r"the image is black \(its largest value is [-+.e\d]+\): no light reached"):
        probvis.render(path)
    lit = write_scene(tmp_path / "lit.xml", sensor(spp=1, sr=1, w=8, h=8) + '<shape type="rectangle"/>'
                      '<emitter type="point"><point name="position" x="0" y="0" z="1"/></emitter>')
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert probvis.render(lit).image.max() > 0
