"""The published alternatives: NEE++'s Russian roulette on a visibility cache, the cache as a control variate,
and Heitz et al.'s ratio estimator.

Renders with the same seed share their camera samples and shadow segments, so the per-seed difference of a
method's image from exact visibility's has expectation zero exactly when the method is unbiased: its mean over
seeds is compared with its standard error (fixed seeds, 4 SE), in the whole image and in the pole's shadow.
"""
import numpy as np
import pytest

import probvis
from probvis.cli import main
from probvis.errors import ProbvisError
from probvis.visibility import RenderPath, VisibilityResult, estimator_class, make_estimator
from probvis.visibility.nee import NEEPlusPlusVisibility
from tests.conftest import sensor, write_scene
from tests.visibility.test_verification import pole_scene

SEEDS = range(24)
COARSE = {"resolution": 4, "pilot": 0.05}  # voxel pairs that straddle the shadow's edge: the cache is often wrong


class WeightlessNEE(NEEPlusPlusVisibility):
    """NEE++ without its 1/p weight: biased (E = p V), to show that the test below sees a bias of this kind."""

    name = "weightless-nee"

    def render_path(self):
        return RenderPath.STAGED

    def evaluate(self, query):
        res = super().evaluate(query)
        _, p = self.cache.plans(self.plan(), query.origin, query.direction)
        return VisibilityResult(res.value * p, res.node_tests, res.triangle_tests, res.aovs)


@pytest.fixture(scope="module")
def scene():
    return pole_scene()


@pytest.fixture(scope="module")
def exact(scene):
    return np.array([probvis.render(scene, seed=s).image for s in SEEDS])


def deviations(scene, exact, visibility, seeds=SEEDS, **render):
    """(mean over seeds of the method's image minus exact's, in its standard error) over the whole image and
    over the pixels exact visibility shows in shadow; and the last render."""
    images, last = [], None
    for s in seeds:
        last = probvis.render(scene, seed=s, visibility=visibility, **render)
        images.append(last.image)
    diff = np.array(images) - exact[:len(images)]
    shadow = exact.mean(axis=(0, 3)) < 0.5 * np.median(exact.mean(axis=(0, 3)))
    out = []
    for d in (diff.mean(axis=(1, 2, 3)), diff[:, shadow].mean(axis=(1, 2))):
        out.append(d.mean() / (np.std(d, ddof=1) / np.sqrt(len(d)) + 1e-300))
    return out, last


@pytest.mark.parametrize("visibility, options", [
    ("nee++", {}),
    ("nee++", {**COARSE, "min_probability": 0.05}),
    ("cache-cv", {}),
    ("cache-cv", COARSE),
    ("cache-cv", {**COARSE, "q": 0.3}),
])
def test_cached_estimators_are_unbiased(scene, exact, visibility, options):
    (whole, shadow), r = deviations(scene, exact, visibility, visibility_options=options)
    assert abs(whole) < 4 and abs(shadow) < 4
    assert 0.05 < r.stats["estimator"]["traced_share"] < 1  # the cache decided: some segments were skipped


def test_the_unbiasedness_test_sees_a_missing_weight():
    bias, se = quad_shadow_bias(WeightlessNEE, 8, 2, range(12))
    assert bias < -4 * se


def test_nee_skips_shadowed_segments_not_lit_ones(scene):
    r = probvis.render(scene, seed=3, visibility="nee++")
    traced = r.aovs["traced"].mean(axis=-1) if r.aovs["traced"].ndim == 3 else r.aovs["traced"]
    shadow = r.image.mean(axis=2) < 0.5 * np.median(r.image.mean(axis=2))
    assert traced[shadow].mean() < 0.5 * traced[~shadow].mean()
    cache = r.stats["estimator"]["cache"]
    assert cache["pilot_segments"] > 0 and cache["pairs"] > 0


def quad_shadow_bias(visibility, shadow_rays, spp, seeds):
    """Mean over seeds of the method's image mean minus exact visibility's (same samples), and its standard error,
    on the built-in quad-shadow (a large blocker's penumbra)."""
    kw = dict(spp=spp, shadow_rays=shadow_rays, resolution=(20, 20))
    d = np.array([probvis.render("quad-shadow", seed=s, visibility=visibility, **kw).image.mean()
                  - probvis.render("quad-shadow", seed=s, **kw).image.mean() for s in seeds])
    return d.mean(), np.std(d, ddof=1) / np.sqrt(len(d))


def spot_away_scene(path):
    """A point light over a floor and a cube, and a wide spot light aimed away from everything: chosen by power,
    most emitter samples fall on the spot, which lights nothing."""
    return write_scene(path, sensor("1, -3, 3", "0, 0, 0", "0, 0, 1", w=8, h=8) + """
        <shape type="rectangle"><transform name="to_world"><scale value="2"/></transform></shape>
        <shape type="cube"><transform name="to_world"><scale value="0.2"/><translate z="0.5"/></transform></shape>
        <emitter type="point"><point name="position" x="0.3" y="0.2" z="2"/><rgb name="intensity" value="4"/></emitter>
        <emitter type="spot"><transform name="to_world"><lookat origin="0, 0, 3" target="0, 0, 4"/></transform>
            <rgb name="intensity" value="16"/><float name="cutoff_angle" value="80"/></emitter>""")


def test_ratio_is_consistent_in_camera_samples_and_shadow_rays(tmp_path):
    """Sweep 50: the ratio formed per camera sample stayed at 0.38x exact visibility's image however many camera
    samples a pixel took, at one shadow ray (a sample whose emitter sample fell on the spot had no light to
    scale; one on the point light gave its analytic light, not weighted by 1/p). Formed per pixel, its bias at one
    sample is the same, and it falls to within the noise as the pixel's camera samples grow, or its shadow
    rays; the render says it is biased."""
    path = spot_away_scene(tmp_path / "s.xml")

    def bias(spp, rays, seeds):
        d = np.array([probvis.render(path, spp=spp, shadow_rays=rays, seed=s, visibility="ratio").image.mean()
                      / probvis.render(path, spp=spp, shadow_rays=rays, seed=s).image.mean() - 1 for s in seeds])
        return d.mean(), np.std(d, ddof=1) / np.sqrt(len(d))

    one, _ = bias(1, 1, range(4))
    assert one < -0.5
    for spp, rays in ((256, 1), (4, 64)):
        b, se = bias(spp, rays, range(8))
        assert 0 < se < 0.01 and abs(b) < 4 * se, (spp, rays, b, se)
    r = probvis.render(path, spp=2, shadow_rays=2, visibility="ratio")
    assert r.stats["estimator"]["biased"]
    # a pixel's samples share its factor: their spread is not the image's noise
    assert r.stats["noise_relmse"] is None and probvis.render(path, spp=2, shadow_rays=2).stats["noise_relmse"] > 0
    from probvis.io.stats import summary

    assert "visibility ratio (biased:" in summary(r.stats)  # the command's summary says so too
    assert "biased" not in summary(probvis.render(path, spp=1, shadow_rays=2).stats)


def test_ratio_gives_lit_points_their_analytic_light():
    """Where every segment of a camera sample is unoccluded the estimate is the analytic light whatever the emitter
    samples: with the same camera samples, 4 and 16 shadow rays give the same lit pixels (exact visibility's
    differ by their noise)."""
    def image(visibility, rays):
        return probvis.render("quad-shadow", spp=1, shadow_rays=rays, resolution=(20, 20), seed=5,
                              visibility=visibility).image

    exact = image("exact", 16)
    lit = exact.mean(axis=-1) > np.median(exact)
    for visibility, share in (("ratio", (0.5, 1.0)), ("exact", (0.0, 0.01))):
        a, b = image(visibility, 4), image(visibility, 16)
        same = np.abs(a - b).max(axis=-1) <= 1e-12 * np.abs(b).max()
        assert share[0] <= same[lit].mean() <= share[1], visibility


def test_ratio_keeps_every_emitter_when_emitters_are_chosen_per_sample(tmp_path):
    """Four emitters (a constant environment, a point, a directional and an area light) chosen by power per
    sample: the ratio is formed per pixel over all of them, so an emitter a camera sample did not choose
    is not lost. At 16 spp x 32 rays the image is within 0.5% of exact visibility's (a ratio per emitter lost 7%);
    its bias grows as the pixel's samples fall."""
    path = write_scene(tmp_path / "four.xml", sensor("0, -4, 2", "0, 0, 0", "0, 0, 1", w=16, h=16) + """
        <shape type="rectangle"><transform name="to_world"><scale value="3"/></transform></shape>
        <shape type="sphere"><point name="center" x="0" y="0" z="0.6"/><float name="radius" value="0.5"/></shape>
        <emitter type="constant"><rgb name="radiance" value="0.5"/></emitter>
        <emitter type="point"><point name="position" x="1" y="-1" z="3"/><rgb name="intensity" value="10"/></emitter>
        <emitter type="directional"><vector name="direction" x="0.3" y="0.2" z="-1"/>
            <rgb name="irradiance" value="1"/></emitter>
        <shape type="rectangle"><transform name="to_world"><scale value="0.3"/><rotate x="1" angle="180"/>
            <translate z="2.5"/></transform><emitter type="area"><rgb name="radiance" value="5"/></emitter></shape>""")

    def bias(spp, rays):
        exact = probvis.render(path, spp=spp, shadow_rays=rays, seed=1).image.mean()
        return probvis.render(path, spp=spp, shadow_rays=rays, seed=1, visibility="ratio").image.mean() / exact - 1

    assert abs(bias(16, 32)) < 0.005
    assert abs(bias(1, 1)) > 2 * abs(bias(16, 32))


@pytest.mark.parametrize("visibility, option, value, message", [
    ("nee++", "min_probability", "0", "min_probability must be from 0.001 to 1"),
    ("nee++", "resolution", "2", "resolution must be from 4 to 256"),
    ("cache-cv", "q", "1.5", "q must be from 0.001 to 1"),
    ("cache-cv", "pilot", "nan", "pilot expects a finite number"),
    ("ratio", "q", "0.5", "visibility 'ratio' has no option 'q'"),
])
def test_bad_options_are_named(visibility, option, value, message):
    with pytest.raises(ProbvisError, match=message):
        make_estimator(visibility, **{option: value})


def test_bad_option_on_the_command_line(tmp_path, capsys):
    assert main(["render", "quad-shadow", "--visibility", "nee++", "--min-probability", "-1",
                 "-o", str(tmp_path / "x.exr")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("probvis: error:") and "min_probability" in err and "\n" not in err
    assert not (tmp_path / "x.exr").exists()


def test_listed_with_their_options(capsys):
    assert main(["estimators"]) == 0
    out = capsys.readouterr().out
    for name in ("nee++", "cache-cv", "ratio"):
        assert name in out


@pytest.mark.parametrize("visibility, options", [("nee++", COARSE), ("cache-cv", COARSE), ("cache-cv", {"q": 0.4}),
                                                 ("ratio", {})])
def test_the_kernel_renders_what_the_staged_path_renders(scene, visibility, options):
    """The estimators render through kernels of their own; `evaluate` (the staged interface) gives the same
    values for the same segments, so the images and test counts agree bit for bit."""
    cls = estimator_class(visibility)
    staged = type("Staged" + cls.__name__, (cls,), {"render_path": lambda self: RenderPath.STAGED})
    a = probvis.render(scene, seed=2, visibility=visibility, visibility_options=options)
    b = probvis.render(scene, seed=2, visibility=staged, visibility_options=options)
    assert a.stats["render_path"] != b.stats["render_path"]
    if visibility == "ratio":  # the kernel scales a sample's sum by its pixel's factor, `evaluate` each segment
        np.testing.assert_allclose(a.image, b.image, rtol=1e-12, atol=0)
    else:
        assert np.array_equal(a.image, b.image)
    assert np.array_equal(a.aovs["triangle_tests"], b.aovs["triangle_tests"])
    for name in a.aovs:  # the second moment is the image's, squared
        if visibility == "ratio" and name == "second_moment":
            np.testing.assert_allclose(a.aovs[name], b.aovs[name], rtol=1e-11, atol=0)
        else:
            assert np.array_equal(a.aovs[name], b.aovs[name]), name


def test_the_ratio_kernel_renders_what_its_staged_path_renders_with_dead_samples(tmp_path):
    """The ratio's pixel factor on both paths where camera samples are shaded but have no segment (all their
    emitter samples on the spot aimed away), with an environment among the emitters, over several batches."""
    path = tmp_path / "s.xml"
    path.write_text(spot_away_scene(tmp_path / "a.xml").read_text().replace(
        "</scene>", "<emitter type='constant'><rgb name='radiance' value='0.2'/></emitter></scene>"))
    cls = estimator_class("ratio")
    staged = type("StagedRatio", (cls,), {"render_path": lambda self: RenderPath.STAGED})
    kw = dict(spp=13, shadow_rays=50, resolution=(37, 23), seed=4)
    from probvis.integrator import TARGET_SLOTS

    assert 37 * 23 * 13 * 50 > 2 * TARGET_SLOTS  # the staged path's batches: three
    a, b = probvis.render(path, visibility="ratio", **kw), probvis.render(path, visibility=staged, **kw)
    assert a.stats["render_path"] != b.stats["render_path"]
    np.testing.assert_allclose(a.image, b.image, rtol=1e-12, atol=0)
    assert np.array_equal(a.aovs["triangle_tests"], b.aovs["triangle_tests"])


def test_the_cache_is_in_the_memory_estimate():
    """A fine grid's rows are counted before they are allocated, and the built cache stays within the estimate."""
    r = probvis.render("quad-shadow", spp=1, shadow_rays=2, resolution=(8, 8), visibility="nee++",
                       visibility_options={"resolution": 200})
    est = make_estimator("nee++", resolution=200).memory_estimate(probvis.load_scene("quad-shadow"),
                                                                  probvis.RenderSettings(spp=1, shadow_rays=2), 64)
    assert est["cache"] >= 8 * 202 ** 3
    assert r.stats["estimator"]["memory_bytes"]["cache"] <= est["cache"]
