"""The splatting film against Mitsuba 3 (scalar_rgb) and against a direct evaluation of its definition: every
camera sample adds w·L and w to the pixels its reconstruction filter covers; a pixel is Σ w·L / Σ w."""
import json
import math
import warnings
from types import SimpleNamespace

import numba
import numpy as np
import pytest

import probvis
from probvis.cli import main
from probvis.errors import ProbvisError
from probvis import film as film_module
from probvis.film import FILTER_CUBIC, FILTER_GAUSSIAN, FILTER_LANCZOS, FILTER_TENT, Film, SplatFilter
from probvis.shading import N_COUNTS
from tests.conftest import mitsuba_image, relmse, write_scene

CROP = ('<integer name="crop_offset_x" value="5"/><integer name="crop_offset_y" value="3"/>'
        '<integer name="crop_width" value="30"/><integer name="crop_height" value="20"/>')
FILTERS = ['<rfilter type="box"/>', '<rfilter type="tent"/>',
           '<rfilter type="tent"><float name="radius" value="1.6"/></rfilter>', "",  # no rfilter: a Gaussian
           '<rfilter type="gaussian"><float name="stddev" value="0.8"/></rfilter>', '<rfilter type="mitchell"/>',
           '<rfilter type="mitchell"><float name="B" value="0"/><float name="C" value="1"/></rfilter>',
           '<rfilter type="catmullrom"/>', '<rfilter type="lanczos"/>',
           '<rfilter type="lanczos"><integer name="lobes" value="2"/></rfilter>']
FILTER_IDS = ["box", "tent", "tent-1.6", "default", "gaussian-0.8", "mitchell", "mitchell-0-1", "catmullrom",
              "lanczos", "lanczos-2"]


def film_scene(tmp_path, rfilter, crop=""):
    """An emitter seen directly (sharp slanted edges), a wall lit by a point light and a small occluder's
    shadow: edges and soft gradients, where a filter's footprint matters."""
    return write_scene(tmp_path / "film.xml", f"""<sensor type="perspective"><float name="fov" value="45"/>
        <transform name="to_world"><lookat origin="0, 0, 3" target="0, 0, 0" up="0, 1, 0"/></transform>
        <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
        <film type="hdrfilm"><integer name="width" value="48"/><integer name="height" value="40"/>{crop}{rfilter}
        </film></sensor><integrator type="direct"><integer name="bsdf_samples" value="0"/></integrator>
        <shape type="rectangle"><transform name="to_world"><rotate z="1" angle="17"/><scale value="0.7"/></transform>
            <emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>
        <shape type="rectangle"><transform name="to_world"><scale value="3"/><translate z="-1"/></transform></shape>
        <shape type="rectangle"><transform name="to_world"><scale value="0.3"/><rotate x="1" angle="30"/>
            <translate x="0.4" y="0.3" z="0.6"/></transform></shape>
        <emitter type="point"><point name="position" x="0" y="2" z="3"/><rgb name="intensity" value="5"/></emitter>
        """, '<default name="spp" value="16"/>')


@pytest.mark.parametrize("crop", ["", CROP], ids=["whole", "crop"])
@pytest.mark.parametrize("rfilter", FILTERS, ids=FILTER_IDS)
def test_noise_and_mean_match_mitsuba_at_equal_samples(tmp_path, rfilter, crop):
    """At 16 spp our error against Mitsuba's converged image is at most 1.3x Mitsuba's own at 16 spp (two
    seeds each), and the image means agree within 1%; filter importance sampling is told apart where the filter
    is wider than a pixel (the comparison bites), and refused for filters with negative lobes, which it cannot
    draw from (Mitchell and Netravali's cubics and Lanczos's sinc, which probvis refused)."""
    path = film_scene(tmp_path, rfilter, crop)
    ref = mitsuba_image(path, 2048, 100)
    theirs = np.mean([relmse(mitsuba_image(path, 16, s), ref) for s in (1, 2)])
    renders = [probvis.render(path, spp=16, seed=s) for s in (1, 2)]
    ours = np.mean([relmse(r.image, ref) for r in renders])
    assert ours <= 1.3 * theirs
    for r in renders:
        np.testing.assert_allclose(r.image.reshape(-1, 3).mean(0), ref.reshape(-1, 3).mean(0), rtol=0.01)
    assert renders[0].stats["film"]["splatting"] == ("box" not in rfilter)
    if any(kind in rfilter for kind in ("mitchell", "catmullrom", "lanczos")):
        with pytest.raises(ProbvisError, match="filter has negative lobes: render without it"):
            probvis.render(path, spp=16, seed=1, filter_importance=True)
    elif "box" not in rfilter:
        fis = probvis.render(path, spp=16, seed=1, filter_importance=True)
        assert not fis.stats["film"]["splatting"]
        assert relmse(fis.image, ref) > 2 * theirs


@pytest.mark.parametrize("rfilter, counted", [('<rfilter type="tent"><float name="radius" value="0.1"/></rfilter>',
                                                "4.0%"),
                                               ('<rfilter type="gaussian"><float name="stddev" value="0.05"/>'
                                                '</rfilter>', "16.0%")])
@pytest.mark.filterwarnings("ignore:.*reach a pixel centre and count")
def test_a_filter_narrower_than_a_pixel_counts_the_samples_it_reaches_as_mitsuba(tmp_path, rfilter, counted):
    """A filter reaching less than half a pixel counts only the samples near a pixel centre, and Mitsuba renders
    it so (a noisy image, not a black one): at equal samples our error against its converged image is its own
    at most 1.3 times; probvis refused such filters as black."""
    with pytest.warns(UserWarning, match=f"{counted} of the camera samples reach a pixel centre and count"):
        path = film_scene(tmp_path, rfilter)
        probvis.load_scene(path)
    ref = mitsuba_image(path, 2048, 100)
    theirs = np.mean([relmse(mitsuba_image(path, 16, s), ref) for s in (1, 2)])
    ours = np.mean([relmse(probvis.render(path, spp=16, seed=s).image, ref) for s in (1, 2)])
    assert ours <= 1.3 * theirs


def test_noise_estimate_follows_the_measured_error(tmp_path):
    """The stats' noise_relmse of a splatted render (each sample's own-pixel variance, weighted by w²) is within
    a factor 2 of its measured error against Mitsuba's converged image, as a box filter's is."""
    for rfilter in ('<rfilter type="box"/>', "", '<rfilter type="tent"/>'):
        path = film_scene(tmp_path, rfilter)
        ref = mitsuba_image(path, 2048, 100)
        r = probvis.render(path, spp=16, seed=3)
        measured = relmse(r.image, ref)
        assert 0.5 * measured < r.stats["noise_relmse"] < 2 * measured, rfilter


def test_images_do_not_depend_on_the_thread_count(tmp_path):
    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("one core")
    path = film_scene(tmp_path, "", CROP)
    a = probvis.render(path, spp=8, seed=4, threads=1)
    b = probvis.render(path, spp=8, seed=4, threads=2)
    np.testing.assert_array_equal(a.image, b.image)
    assert a.stats["noise_relmse"] == b.stats["noise_relmse"]


def _weight(f, x):
    x = abs(x)
    if f.kind == FILTER_TENT:
        return max(0.0, 1.0 - x / f.radius)
    if f.kind == FILTER_CUBIC:  # Mitchell and Netravali's (1988) eq. 8
        b, c = f.b, f.c
        if x < 1:
            return ((12 - 9 * b - 6 * c) * x ** 3 + (-18 + 12 * b + 6 * c) * x ** 2 + (6 - 2 * b)) / 6
        if x < 2:
            return ((-b - 6 * c) * x ** 3 + (6 * b + 30 * c) * x ** 2 + (-12 * b - 48 * c) * x + (8 * b + 24 * c)) / 6
        return 0.0
    if f.kind == FILTER_LANCZOS:
        return float(np.sinc(x) * np.sinc(x / f.radius)) if x <= f.radius else 0.0
    return max(0.0, math.exp(f.alpha * x * x) - f.bias)


def wvar_ref_of(f, xy, var, width, height):
    """Σ w²·σ² per pixel, sample by sample."""
    out = np.zeros((width * height, 3))
    for (x, y), v in zip(xy, var):
        for ty in range(height):
            for tx in range(width):
                out[ty * width + tx] += (_weight(f, tx + 0.5 - x) * _weight(f, ty + 0.5 - y)) ** 2 * v
    return out


@pytest.mark.parametrize("f", [SplatFilter(FILTER_TENT, 1.0, 0.0, 0.0), SplatFilter(FILTER_TENT, 2.3, 0.0, 0.0),
                               SplatFilter(FILTER_GAUSSIAN, 2.0, -2.0, math.exp(-8.0)),
                               SplatFilter(FILTER_CUBIC, 2.0, 0.0, 0.0, 1 / 3, 1 / 3),
                               SplatFilter(FILTER_CUBIC, 2.0, 0.0, 0.0, 0.0, 0.5),
                               SplatFilter(FILTER_LANCZOS, 3.0, 0.0, 0.0)],
                         ids=["tent", "tent-2.3", "gaussian", "mitchell", "catmullrom", "lanczos"])
@pytest.mark.parametrize("chunk_bytes", [None, 1], ids=["whole", "pixel-chunks"])
def test_splat_kernel_is_the_definition_over_batches_that_split_rows(f, chunk_bytes, monkeypatch):
    """The film's splat, fed in batches that end mid-row (and in chunks of one pixel), against every sample
    splatted one by one."""
    if chunk_bytes is not None:
        monkeypatch.setattr(film_module, "SPLAT_CHUNK_BYTES", chunk_bytes)
        monkeypatch.setattr(film_module, "SPLAT_MIN_ROWS", 0)
    rng = np.random.default_rng(5)
    width, height, spp = 7, 5, 3
    n = width * height
    pix = np.repeat(np.arange(n), spp)
    xy = np.stack([pix % width + rng.random(len(pix)), pix // width + rng.random(len(pix))], axis=1)
    rad = rng.random((len(pix), 3))
    film = Film(width, height, spp, 1, rfilter=f)
    for p0, p1 in ((0, 4), (4, 16), (16, 17), (17, n)):
        sl = slice(p0 * spp, p1 * spp)
        film.add(SimpleNamespace(pixel=np.arange(p0, p1), film_xy=xy[sl]),
                 SimpleNamespace(radiance=rad[sl], counts=np.zeros((p1 - p0, N_COUNTS), np.int64), aovs=None))
    sums = [film.weight, film.image, film.weighted_var, film.moment2]
    w_ref, wl_ref = np.zeros(n), np.zeros((n, 3))
    for (x, y), v in zip(xy, rad):
        for ty in range(height):
            for tx in range(width):
                w = _weight(f, tx + 0.5 - x) * _weight(f, ty + 0.5 - y)
                w_ref[ty * width + tx] += w
                wl_ref[ty * width + tx] += w * v
    np.testing.assert_allclose(sums[0], w_ref, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(sums[1], wl_ref, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(sums[3], (rad ** 2).reshape(n, spp, 3).mean(1), rtol=1e-12)  # per pixel of origin
    var = rad.reshape(n, spp, 3).var(1, ddof=1)[pix]  # each sample's own pixel's sample variance
    np.testing.assert_allclose(sums[2], wvar_ref_of(f, xy, var, width, height), rtol=1e-12, atol=1e-15)


def test_filter_importance_from_the_command_line(tmp_path, capsys):
    path = film_scene(tmp_path, '<rfilter type="tent"/>')
    stats = tmp_path / "s.json"
    assert main(["render", str(path), "--spp", "2", "--filter-importance", "-q", "-o", str(tmp_path / "a.exr"),
                 "--stats", str(stats)]) == 0
    film = json.loads(stats.read_text())["film"]
    assert {k: film[k] for k in ("filter", "splatting", "filter_importance")} == {
        "filter": "tent", "splatting": False, "filter_importance": True}
    assert film["seconds"] > 0.0


@pytest.mark.parametrize("value", ["yes", 1, "0"])
def test_bad_filter_importance_is_refused(value):
    with pytest.raises(ProbvisError, match="filter_importance must be True or False"):
        probvis.render("quad-shadow", spp=1, filter_importance=value)


@pytest.mark.parametrize("rfilter, message", [
    ('<rfilter type="tent"><float name="radius" value="100"/></rfilter>', "at most 32 pixels"),
    ('<rfilter type="gaussian"><float name="stddev" value="9"/></rfilter>', "at most 8 pixels"),
    ('<rfilter type="gaussian"><float name="stddev" value="0"/></rfilter>', "must be positive"),
    ('<rfilter type="lanczos"><integer name="lobes" value="0"/></rfilter>', "lobes must be from 1 to 32, got 0"),
    ('<rfilter type="mitchell"><float name="B" value="1e9"/></rfilter>', "B and C must be within ±100"),
    ('<rfilter type="catmullrom"><float name="B" value="1"/></rfilter>', "unsupported parameter 'B'"),
    ('<rfilter type="sinc"/>', "unsupported rfilter 'sinc' \\(supported: box, tent, gaussian, mitchell"),
])
def test_filters_beyond_the_film_s_reach_are_refused(tmp_path, rfilter, message):
    with pytest.raises(ProbvisError, match=message):
        probvis.load_scene(film_scene(tmp_path, rfilter))


@pytest.mark.parametrize("b, c, warned", [(-100, 100, True), (1.5, 0, True), (0, 1, False), (1 / 3, 1 / 3, False)])
def test_a_mitchell_filter_outside_its_family_is_warned_of(tmp_path, b, c, warned):
    """B = -100, C = 100 rendered a ringing image (pixels -0.57 to 3.6 where the box filter gives 0.05) unsaid."""
    path = film_scene(tmp_path, f'<rfilter type="mitchell"><float name="B" value="{b}"/><float name="C" value="{c}"/>'
                                '</rfilter>')
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        probvis.load_scene(path)
    ringing = [str(w.message) for w in said if "outside 0 to 1: its lobes ring" in str(w.message)]
    assert len(ringing) == int(warned), ringing


def test_one_sample_per_pixel_has_no_noise_estimate():
    """With one camera sample per pixel the per-pixel variance is unknown: noise_relmse is None, not 0."""
    one = probvis.render("quad-shadow", resolution=(8, 8), spp=1, shadow_rays=1)
    two = probvis.render("quad-shadow", resolution=(8, 8), spp=2, shadow_rays=1)
    assert one.stats["noise_relmse"] is None and two.stats["noise_relmse"] > 0.0


def test_a_new_resolution_on_a_cropped_film_says_the_crop_is_dropped(tmp_path):
    """`resolution=` on a scene with a crop window rendered the whole view without a word."""
    path = film_scene(tmp_path, '<rfilter type="box"/>', CROP)
    with pytest.warns(UserWarning, match=r"the new resolution renders the whole view, not the film's crop window "
                                         r"\(30x20 at \(5, 3\) of 48x40\)"):
        img = probvis.render(path, spp=1, resolution=(12, 10)).image
    assert img.shape == (10, 12, 3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        probvis.render(film_scene(tmp_path, '<rfilter type="box"/>'), spp=1, resolution=(12, 10))
