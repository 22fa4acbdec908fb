"""Verification (correction terms): the occlusion map and probabilistic visibility converge to the true image.

The scene is built so that photons miss a blocker: a thin pole under a small light, few photons. Renders with
the same seed share their camera samples, so the per-seed difference of a method's image from exact
visibility's has expectation zero exactly when the method is unbiased; its mean over seeds is compared with
its standard error (fixed seeds, 4 SE).
"""
import numpy as np
import pytest

import probvis
from probvis.cli import main
from probvis.errors import ProbvisError
from probvis.scene import Camera, SceneBuilder
from probvis.scene import shapes as shp
from probvis.scene import transform as tf
from probvis.settings import RenderSettings
from probvis.visibility import make_estimator

SEEDS = range(24)


def pole_scene():
    """A floor, a small square light 2 above it, and a thin pole (0.04 x 0.04 x 1.2) standing under the light."""
    b = SceneBuilder("pole")
    v, f = shp.rectangle()
    b.add_mesh("floor", "rectangle", v, f, tf.scale([1.5, 1.5, 1]), b.material((0.8, 0.8, 0.8)))
    cv, cf = shp.cube()
    b.add_mesh("pole", "cube", cv, cf, tf.translate([0.1, 0.0, 0.6]) @ tf.scale([0.02, 0.02, 0.6]),
               b.material((0.5, 0.5, 0.5)))
    light = tf.translate([0.0, 0.0, 2.0]) @ tf.rotate([1, 0, 0], 180) @ tf.scale([0.15, 0.15, 1])
    b.add_mesh("light", "rectangle", v, f, light, None, radiance=(20.0, 20.0, 20.0))
    cam = Camera(tf.look_at([0.1, 0.0, 3.0], [0.1, 0.0, 0.0], [0, 1, 0]), 20.0, 20, 20)
    return b.build(cam, RenderSettings(spp=4, shadow_rays=16))


@pytest.fixture(scope="module")
def scene():
    return pole_scene()


@pytest.fixture(scope="module")
def exact(scene):
    return np.array([probvis.render(scene, seed=s).image.mean() for s in SEEDS])


def deviation(scene, exact, visibility, **options):
    """Mean over seeds of (method - exact) image means, in units of its standard error."""
    diff = np.array([probvis.render(scene, seed=s, visibility=visibility,
                                    visibility_options={"photons": 3000, "neighbours": 16, **options}).image.mean()
                     for s in SEEDS]) - exact
    return diff.mean() / (np.std(diff, ddof=1) / np.sqrt(len(diff)) + 1e-300)


def test_without_verification_the_shortcuts_are_biased(scene, exact):
    assert deviation(scene, exact, "occlusion-map", verify="off") > 4  # the pole's shadow taken for lit: too bright
    assert deviation(scene, exact, "occlusion-map", penumbra="list", verify="off") > 4


@pytest.mark.parametrize("visibility, options", [
    ("occlusion-map", {}),
    ("occlusion-map", {"penumbra": "list"}),
    ("occlusion-map", {"penumbra": "list", "adaptive_photons": True}),
    ("occlusion-map", {"penumbra": "list", "verify": "1"}),
    ("occlusion-map", {"verify": "0.3"}),
    ("probvis", {"estimator": "shifted"}),
    ("probvis", {"estimator": "adaptive"}),
    ("probvis", {"estimator": "power", "power": 4, "verify": "0.5"}),
])
def test_verified_estimators_are_unbiased(scene, exact, visibility, options):
    assert abs(deviation(scene, exact, visibility, **options)) < 4


def test_verification_is_reported_per_case(scene):
    r = probvis.render(scene, seed=1, visibility="occlusion-map",
                       visibility_options={"photons": 3000, "neighbours": 16, "penumbra": "list"})
    v = r.stats["estimator"]["verification"]
    assert v["setting"] == "auto" and not v["biased"]
    assert v["lit"]["pairs"] > 0 and 0 < v["lit"]["verified_pair_share"] < 1
    assert v["lit"]["verified_segments"] > 0 and v["lit"]["mismatch_mean"] < 0  # the pole's missed shadow
    off = probvis.render(scene, seed=1, visibility="occlusion-map", visibility_options={"verify": "off"})
    assert off.stats["estimator"]["verification"]["biased"]
    assert off.stats["estimator"]["verification"]["lit"]["verified_segments"] == 0


@pytest.mark.parametrize("value", ["0", "1.5", "nan", "-0.2", "sometimes"])
def test_bad_verify_values_are_named(value):
    with pytest.raises(ProbvisError, match="verify must be auto, off or a probability in"):
        make_estimator("occlusion-map", verify=value)


def test_verify_does_not_apply_to_exact(tmp_path, capsys):
    assert main(["render", "quad-shadow", "--verify", "0.5", "-o", str(tmp_path / "x.exr")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("probvis: error: --verify does not apply to --visibility exact")
