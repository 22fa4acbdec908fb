"""Environment emitters (`envmap`, `constant`) against Mitsuba 3 (scalar_rgb): radiance per direction, renders,
image files; and the occlusion map and probabilistic visibility staying unbiased under them."""
import dataclasses
import re
import warnings

import numpy as np
import pytest

import probvis
from probvis import ProbvisError
from probvis.emitters import build_emitter_sampler
from probvis.environment import environment_radiance, sample_environment
from probvis.io.image import write_exr
from probvis.io.linear_rgb import read_linear_rgb
from tests.conftest import assert_matches_mitsuba, mitsuba_image, sensor, write_scene

GROUND = """
    <shape type="rectangle"><transform name="to_world"><scale value="3"/><rotate x="1" angle="-90"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.6, 0.5"/></bsdf></shape>
    <shape type="cube"><transform name="to_world"><scale value="0.5"/><rotate y="1" angle="20"/>
        <translate y="0.5"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.3, 0.6, 0.2"/></bsdf></shape>"""
ENVMAP = """
    <emitter type="envmap"><string name="filename" value="sky.exr"/><float name="scale" value="1.5"/>
        <transform name="to_world"><rotate y="1" angle="30"/><rotate x="1" angle="10"/></transform></emitter>"""
CONSTANT = """
    <emitter type="constant"><rgb name="radiance" value="0.8, 1.0, 1.2"/></emitter>"""
CAMERA = dict(origin="0, 3, 5", target="0, 0.3, 0", fov=55, spp="$spp", w=40, h=30, sr=1)


def sky(h=16, w=32):
    """A skewed random sky with a small bright sun."""
    img = np.random.default_rng(3).random((h, w, 3)) ** 3 * 2
    img[3:5, 5:8] = 6.0
    return img.astype(np.float32)


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    d = tmp_path_factory.mktemp("environment")
    write_exr(d / "sky.exr", sky())
    spp = '<default name="spp" value="16"/>'
    return {"envmap": write_scene(d / "envmap.xml", sensor(**CAMERA) + GROUND + ENVMAP, spp),
            "constant": write_scene(d / "constant.xml", sensor(**CAMERA) + GROUND + CONSTANT, spp)}


def test_envmap_radiance_is_mitsubas_in_every_direction(scenes):
    """Bilinear between pixel centres, half a texel in, the map rotated by to_world and scaled."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    ours = probvis.load_scene(scenes["envmap"])
    es = build_emitter_sampler(ours).arrays
    emitter = mi.load_file(str(scenes["envmap"]), spp=1).emitters()[0]
    dirs = np.random.default_rng(0).normal(size=(200, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    for d in dirs:
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*(-d))
        expected = np.array(emitter.eval(si))
        got = np.array(environment_radiance(es, *d)) * ours.emitter_radiance[0]
        np.testing.assert_allclose(got, expected, rtol=2e-5, atol=1e-5)


def test_environment_sampling_integrates_the_radiance(scenes):
    """E[L(w) / pdf(w)] over sampled directions is the integral of L over the sphere (by quadrature), within 4
    standard errors; the radiance a sample carries is the radiance of its direction."""
    es = build_emitter_sampler(probvis.load_scene(scenes["envmap"])).arrays
    u = np.random.default_rng(1).random((40000, 3))
    samples = np.array([sample_environment(es, *v) for v in u])
    d, pdf, radiance = samples[:, :3], samples[:, 3], samples[:, 4:]
    assert np.all(pdf > 0)
    np.testing.assert_allclose(radiance[:50], [environment_radiance(es, *w) for w in d[:50]], rtol=1e-9, atol=1e-12)
    ratio = radiance / pdf[:, None]
    theta = (np.arange(400) + 0.5) * np.pi / 400
    phi = (np.arange(800) + 0.5) * 2 * np.pi / 800
    t, p = np.meshgrid(theta, phi, indexing="ij")
    grid = np.stack([np.sin(t) * np.sin(p), np.cos(t), -np.sin(t) * np.cos(p)], -1).reshape(-1, 3)
    weight = (np.sin(t) * (np.pi / 400) * (2 * np.pi / 800)).ravel()
    integral = (np.array([environment_radiance(es, *w) for w in grid]) * weight[:, None]).sum(0)
    se = ratio.std(0, ddof=1) / np.sqrt(len(ratio))
    assert np.all(np.abs(ratio.mean(0) - integral) < 4 * se), (ratio.mean(0), integral, se)


def test_environment_sampling_density_is_mitsubas(scenes):
    """Directions are sampled with Mitsuba's envmap density (its bilinear warp of luminance x sin θ): the pdf
    of each sampled direction is what Mitsuba's `pdf_direction` gives for it."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    es = build_emitter_sampler(probvis.load_scene(scenes["envmap"])).arrays
    emitter = mi.load_file(str(scenes["envmap"]), spp=1).emitters()[0]
    u = np.random.default_rng(2).random((300, 3))
    it = mi.Interaction3f()
    for v in u:
        d = sample_environment(es, *v)
        ds = mi.DirectionSample3f()
        ds.d = mi.Vector3f(*d[:3])
        assert d[3] == pytest.approx(float(emitter.pdf_direction(it, ds)), rel=2e-3)


def _compensated(scenes, path, bsdf_samples):
    """The envmap scene with mis_compensation, at `path`."""
    text = scenes["envmap"].read_text().replace('value="sky.exr"', f'value="{scenes["envmap"].parent / "sky.exr"}"')
    text = text.replace('<float name="scale" value="1.5"/>',
                        '<float name="scale" value="1.5"/><boolean name="mis_compensation" value="true"/>')
    path.write_text(text.replace('<integer name="bsdf_samples" value="0"/>',
                                 f'<integer name="bsdf_samples" value="{bsdf_samples}"/>'))
    return path


def _assert_mean_is_mitsubas(path):
    """The image's mean within 4 standard errors (each from two seeds' pixel differences) and 1% of Mitsuba's."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ours = [probvis.render(path, spp=64, shadow_rays=4, seed=s).image.reshape(-1, 3) for s in (1, 2)]
    theirs = [mitsuba_image(path, 256, s).reshape(-1, 3) for s in (1, 2)]
    se2 = sum((x - y).std(0) ** 2 / 4 / len(x) for x, y in (ours, theirs))
    gap = (ours[0] + ours[1] - theirs[0] - theirs[1]).mean(0) / 2
    assert np.all(np.abs(gap) < 4 * np.sqrt(se2)), (gap, np.sqrt(se2))
    assert np.all(np.abs(gap) < 0.01 * theirs[0].mean(0))


def test_mis_compensation_samples_and_renders_as_mitsuba_s(scenes, tmp_path):
    """`mis_compensation` samples the map by its luminance less the mean (Mitsuba's density, direction by
    direction); under `direct` without BSDF samples the dimmer directions' light is then missing in both
    renderers alike, and probvis says so."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    path = _compensated(scenes, tmp_path / "mis.xml", 0)
    with pytest.warns(UserWarning, match="mis_compensation samples the map by its luminance less the mean"):
        scene = probvis.load_scene(path)
    es = build_emitter_sampler(scene).arrays
    emitter = mi.load_file(str(path), spp=1).emitters()[0]
    it = mi.Interaction3f()
    for v in np.random.default_rng(5).random((300, 3)):
        d = sample_environment(es, *v)
        ds = mi.DirectionSample3f()
        ds.d = mi.Vector3f(*d[:3])
        assert d[3] == pytest.approx(float(emitter.pdf_direction(it, ds)), rel=2e-3)
    plain = build_emitter_sampler(probvis.load_scene(scenes["envmap"])).arrays
    inner = slice(1, -1)  # the poles' rows are zero in both (sin θ)
    assert (es.env_density[inner] == 0).mean() > 0.5 and not (plain.env_density[inner] == 0).any()
    _assert_mean_is_mitsubas(path)


def test_mis_compensation_with_bsdf_samples_has_the_whole_map_s_light_as_in_mitsuba(scenes, tmp_path):
    """With BSDF samples (Mitsuba's default), Mitsuba's MIS gathers the dimmer directions' light by BSDF sampling:
    its image has the whole map's light, and probvis's, sampling the whole map, the same mean (it was 15-22%
    darker: sampled as without BSDF samples)."""
    pytest.importorskip("mitsuba")
    path = _compensated(scenes, tmp_path / "mis.xml", 1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warnings.filterwarnings("ignore", message=".*bsdf_samples")  # probvis samples no BSDF: said as usual
        scene = probvis.load_scene(path)
    assert (build_emitter_sampler(scene).arrays.env_density[1:-1] > 0).all()  # the whole map sampled
    _assert_mean_is_mitsubas(path)


@pytest.mark.parametrize("kind", ["envmap", "constant"])
def test_environment_lit_scene_matches_mitsuba(scenes, kind):
    """Camera rays that miss see the environment; one emitter sample per camera sample, as Mitsuba's."""
    assert_matches_mitsuba(scenes[kind], shadow_rays=1)


def test_environment_lit_scene_with_mitsuba_s_default_filter(scenes, tmp_path):
    """The envmap scene without an rfilter (Mitsuba's Gaussian): splatted as Mitsuba's film, no noisier."""
    text = scenes["envmap"].read_text().replace('<rfilter type="box"/>', "")
    path = tmp_path / "gaussian.xml"
    path.write_text(text.replace('value="sky.exr"', f'value="{scenes["envmap"].parent / "sky.exr"}"'))
    assert_matches_mitsuba(path, shadow_rays=1)


@pytest.mark.parametrize("kind, visibility, options", [
    ("envmap", "occlusion-map", {"photons": 20000}),
    ("envmap", "probvis", {"photons": 20000, "estimator": "shifted"}),
    ("constant", "occlusion-map", {"photons": 20000, "penumbra": "list"}),
    ("constant", "probvis", {"photons": 20000}),
])
def test_occlusion_map_under_an_environment_is_unbiased(scenes, kind, visibility, options):
    """Photons come from a disk beyond the scene, directions by the map's luminance; a constant environment's
    lit points take its closed form (pi L), an envmap's are sampled. Paired by seed with exact visibility, the
    difference averages to zero."""
    scene = probvis.load_scene(scenes[kind])

    def mean(seed, **vis):
        return probvis.render(scene, spp=2, shadow_rays=2, seed=seed, **vis).image.mean()

    diff = np.array([mean(s, visibility=visibility, visibility_options=options) - mean(s) for s in range(12)])
    assert abs(diff.mean()) < 4 * np.std(diff, ddof=1) / np.sqrt(len(diff))
    r = probvis.render(scene, spp=2, shadow_rays=2, visibility=visibility, visibility_options=options)
    assert r.stats["estimator"]["photons"] > 0
    cases = r.stats["cases"]
    assert (cases["lit"]["count"] > 0) == (kind == "constant")


@pytest.mark.parametrize("suffix", [".hdr", ".png", ".exr"])
def test_image_files_read_as_mitsuba_reads_them(tmp_path, suffix):
    """Linear RGB as Mitsuba's bitmap loader gives it (PNG decoded from sRGB)."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    import cv2
    import imageio.v3 as iio

    img = np.random.default_rng(2).random((6, 9, 3)).astype(np.float32) * 4
    path = tmp_path / f"img{suffix}"
    if suffix == ".hdr":
        cv2.imwrite(str(path), img[..., ::-1])
    elif suffix == ".png":
        iio.imwrite(path, (img / 4 * 255).astype(np.uint8))
    else:
        write_exr(path, img)
    expected = np.array(mi.Bitmap(str(path)).convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32, False))
    np.testing.assert_allclose(read_linear_rgb(path), expected, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("emitter, message", [
    ('<emitter type="envmap"><string name="filename" value="missing.exr"/></emitter>', "image not found"),
    ('<emitter type="envmap"><string name="filename" value="broken.hdr"/></emitter>', "cannot read Radiance HDR"),
    ('<emitter type="envmap"><string name="filename" value="sky.exr"/><transform name="to_world"><scale value="2"/>'
     '</transform></emitter>', "must be a rotation"),
    ('<emitter type="envmap"><string name="filename" value="sky.txt"/></emitter>', "unsupported image format"),
    ('<emitter type="envmap"/>', "needs a 'filename'"),
    ('<emitter type="constant"/><emitter type="constant"/>', "only one environment emitter"),
    ('<emitter type="constant"><rgb name="radiance" value="-1"/></emitter>', "non-negative"),
])
def test_bad_environment_names_file_and_line(tmp_path, emitter, message):
    write_exr(tmp_path / "sky.exr", sky())
    (tmp_path / "broken.hdr").write_text("not an image")
    (tmp_path / "sky.txt").write_text("not an image")
    path = write_scene(tmp_path / "bad.xml", sensor() + GROUND + emitter)
    with pytest.raises(ProbvisError, match=message) as err:
        probvis.load_scene(path)
    assert "bad.xml:" in str(err.value)


def test_an_environment_map_s_memory_is_estimated_before_it_is_read_or_built(scenes, tmp_path, monkeypatch):
    """An image too large to decode is refused from its header, naming it; an environment map's sampling tables
    are a part of the render's estimate (a 10000x10000 map ran out of memory after 20 s)."""
    from PIL import Image

    from probvis import memory
    big = tmp_path / "big.png"
    Image.fromarray(np.full((600, 800), 128, np.uint8)).save(big)
    monkeypatch.setattr(memory, "available", lambda: 600 * 800 * 50)  # below a grey image's 56 bytes a pixel
    with pytest.raises(ProbvisError, match=r"big.png: a 800x600 image needs about .* GiB to read as linear RGB"):
        read_linear_rgb(big)
    monkeypatch.setattr(memory, "available", lambda: 5 << 20)
    scene = probvis.load_scene(scenes["envmap"])
    scene = dataclasses.replace(scene, environment=dataclasses.replace(scene.environment, image=np.ones((400, 800, 3))))
    with pytest.raises(ProbvisError, match=r"needs about .*environment .* lower the environment map's size"):
        probvis.render(scene, spp=1, shadow_rays=1, resolution=(8, 8))


def test_an_environment_image_edited_beyond_the_emission_bound_is_refused(scenes):
    """A texel set to 1e300 after loading rendered an image of mean 4.7e297; the same value in the file, or in
    an edited emitter_radiance, is refused."""
    scene = probvis.load_scene(scenes["envmap"])
    image = scene.environment.image.copy()
    image[0, 0] = 1e300
    scene = dataclasses.replace(scene, environment=dataclasses.replace(scene.environment, image=image))
    with pytest.raises(ProbvisError, match=r"scene.environment must hold a .* image of values from 0 to 1e\+30"):
        probvis.render(scene, spp=1, shadow_rays=1, resolution=(8, 8))


def test_hidden_emitters_are_black_where_seen_as_in_mitsuba(tmp_path):
    """`hide_emitters`: the area light and the sky are not seen directly (the sky black), what they light is
    (probvis refused the option); the image against Mitsuba's, the sky's pixels black, and the `path`
    integrator's option read as the `direct` one's."""
    hide = '<boolean name="hide_emitters" value="true"/>'
    head = sensor(origin="0, -2, 1.2", target="0, 0, 0.3", up="0, 0, 1", spp="$spp", w=24, h=24, sr=4)
    head = head.replace('<integer name="bsdf_samples" value="0"/>', '<integer name="bsdf_samples" value="0"/>' + hide)
    body = """
        <emitter type="constant"><rgb name="radiance" value="0.3"/></emitter>
        <shape type="rectangle"><bsdf type="diffuse"/></shape>
        <shape type="rectangle"><transform name="to_world"><scale value="0.2"/><rotate x="1" angle="60"/>
            <translate y="0.3" z="0.5"/></transform><emitter type="area"><rgb name="radiance" value="8"/></emitter>
        </shape>"""
    path = write_scene(tmp_path / "h.xml", head + body, '<default name="spp" value="16"/>')
    image = probvis.render(path, spp=4).image
    shown = probvis.render(write_scene(tmp_path / "s.xml", head.replace(hide, "") + body,
                                       '<default name="spp" value="16"/>'), spp=4).image
    assert image.max() < 2.0 < shown.max()  # the light itself (radiance 8) is seen only when shown
    assert image[0, 0].max() == 0.0 < shown[0, 0].min()  # the sky in the top corner
    as_path = re.sub(r'<integrator.*?</integrator>', f'<integrator type="path">{hide}</integrator>', head, flags=re.S)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "rendered as its direct-illumination component"
        path_image = probvis.render(write_scene(tmp_path / "p.xml", as_path + body, '<default name="spp" '
                                                'value="16"/>'), spp=4, shadow_rays=4).image
    np.testing.assert_array_equal(path_image, image)
    pytest.importorskip("mitsuba", minversion="3.9")  # older versions hid only the emission
    assert_matches_mitsuba(path, shadow_rays=4)
    lit = body.replace('<emitter type="area">', '<bsdf type="diffuse"/><emitter type="area">')
    assert lit != body  # the emitter with a BSDF of its own, which the sky lights: Mitsuba 3.9 hides it whole (the
    # camera sees the black sky through it)
    assert_matches_mitsuba(write_scene(tmp_path / "b.xml", head + lit, '<default name="spp" value="16"/>'),
                           shadow_rays=4)


def test_hidden_emitters_let_the_camera_see_what_lies_behind_them(tmp_path):
    """Mitsuba 3.9 passes camera rays through emitting shapes under `hide_emitters`: a light between the camera
    and a lit floor shows the floor, through any number of lights (probvis drew the light black); the lights
    still cast their shadows and light the floor."""
    hide = '<boolean name="hide_emitters" value="true"/>'
    head = sensor(origin="0, 0, 4", target="0, 0, 0", spp="$spp", w=16, h=16, sr=4)
    head = head.replace('<integer name="bsdf_samples" value="0"/>', '<integer name="bsdf_samples" value="0"/>' + hide)
    light = """<shape type="rectangle"><transform name="to_world"><scale value="{s}"/><rotate x="1" angle="180"/>
        <translate z="{z}"/></transform><emitter type="area"><rgb name="radiance" value="{r}"/></emitter></shape>"""
    body = (light.format(s=0.5, z=2, r=5) + light.format(s=0.3, z=1, r=1) + light.format(s=0.2, z=0.5, r=1)
            + '<shape type="rectangle"><transform name="to_world"><scale value="2"/></transform><bsdf type="diffuse"/>'
              '</shape>')
    path = write_scene(tmp_path / "h.xml", head + body, '<default name="spp" value="16"/>')
    out = probvis.render(path, spp=4)
    shown = probvis.render(write_scene(tmp_path / "s.xml", head.replace(hide, "") + body,
                                       '<default name="spp" value="16"/>'), spp=4).image
    assert shown[5:11, 5:11].max() == 0.0  # the top light's back, which emits and reflects nothing
    assert out.image[5:11, 5:11].mean() > 0.05  # the floor under the lights, seen through all three
    assert out.stats["camera_rays"] == 16 * 16 * 4
    pytest.importorskip("mitsuba", minversion="3.9")  # older versions drew the lights black, as probvis did
    assert_matches_mitsuba(path, shadow_rays=4)


@pytest.mark.parametrize("h, w", [(1, 1), (1, 2), (2, 1), (2, 2)])
def test_an_environment_map_smaller_than_2x3_renders_as_mitsuba_pads_it(tmp_path, h, w):
    """Mitsuba repeats a small map's last row and column up to 3 rows and 2 columns (its stored data shows it);
    probvis refused maps below 2x3."""
    write_exr(tmp_path / "e.exr", np.random.default_rng(h * 3 + w).random((h, w, 3)) + 0.2)
    head = sensor(origin="0, 0, 1", target="1, 0.3, 1", up="0, 0, 1", fov=90, spp="$spp", w=16, h=16, sr=1)
    path = write_scene(tmp_path / "s.xml", head + """<emitter type="envmap"><string name="filename" value="e.exr"/>
        </emitter><shape type="rectangle"><transform name="to_world"><scale value="3"/></transform></shape>""",
                       '<default name="spp" value="16"/>')
    assert_matches_mitsuba(path, shadow_rays=1)
