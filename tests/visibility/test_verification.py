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


def deviation(scene, exact, visibility, seeds=SEEDS, **options):
    """Mean over seeds of (method - exact) image means, in units of its standard error."""
    options = {"photons": 3000, "neighbours": 16, **options}
    diff = np.array([probvis.render(scene, seed=s, visibility=visibility, visibility_options=options).image.mean()
                     for s in seeds]) - exact
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
    ("probvis", {"estimator": "shifted", "verify": "1"}),
    ("probvis", {"estimator": "standard", "levels": 2}),
    ("probvis", {"estimator": "shifted", "cells": 2, "grouping": "random", "volumetric": False}),
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


@pytest.mark.parametrize("visibility", ["occlusion-map", "probvis"])
def test_segments_verified_with_certainty_are_traced_alone(scene, visibility):
    """With q = 1 a penumbra segment's value V_list + (V - V_list) / q is V: it is traced, its list untested
    (no candidate culled or tested), and it counts as verified but not as measured."""
    opts = {"photons": 3000, "neighbours": 16, "verify": "1", **({"penumbra": "list"} if visibility ==
                                                                  "occlusion-map" else {})}
    r = probvis.render(scene, seed=1, visibility=visibility, visibility_options=opts)
    est = r.stats["estimator"]
    pen = est["verification"]["penumbra"]
    assert pen["segments"] > 0 and pen["verified_segments"] == pen["segments"] and pen["measured_segments"] == 0
    assert pen["mean_q"] == 1.0 and est["culled_candidates"] == 0
    assert sum(est.get("term_selections", [0])) == 0
    half = probvis.render(scene, seed=1, visibility=visibility, visibility_options={**opts, "verify": "0.999"})
    assert half.stats["estimator"]["verification"]["penumbra"]["measured_segments"] > 0


@pytest.mark.parametrize("value", ["0", "1.5", "nan", "-0.2", "sometimes"])
def test_bad_verify_values_are_named(value):
    with pytest.raises(ProbvisError, match="verify must be auto, off or a probability from 0.001 to 1"):
        make_estimator("occlusion-map", verify=value)


def test_verify_does_not_apply_to_exact(tmp_path, capsys):
    assert main(["render", "quad-shadow", "--verify", "0.5", "-o", str(tmp_path / "x.exr")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("probvis: error: --verify does not apply to --visibility exact")


def hole_scene():
    """A floor under a wide blocker with a small square hole, lit by a small light right above the hole: the
    light through the hole reaches a patch whose few photons are mostly shadow photons (taken as shadowed)."""
    b = SceneBuilder("hole")
    v, f = shp.rectangle()
    grey = b.material((0.8, 0.8, 0.8))
    b.add_mesh("floor", "rectangle", v, f, tf.scale([1.5, 1.5, 1]), grey)
    side = b.material((0.5, 0.5, 0.5), twosided=True)
    h = 0.03  # half-width of the hole
    for name, (x0, x1, y0, y1) in {"left": (-1.5, -h, -1.5, 1.5), "right": (h, 1.5, -1.5, 1.5),
                                   "front": (-h, h, -1.5, -h), "back": (-h, h, h, 1.5)}.items():
        m = tf.translate([(x0 + x1) / 2, (y0 + y1) / 2, 0.8]) @ tf.scale([(x1 - x0) / 2, (y1 - y0) / 2, 1])
        b.add_mesh(name, "rectangle", v, f, m, side)
    light = tf.translate([0.0, 0.0, 2.0]) @ tf.rotate([1, 0, 0], 180) @ tf.scale([0.1, 0.1, 1])
    b.add_mesh("light", "rectangle", v, f, light, None, radiance=(200.0, 200.0, 200.0))
    cam = Camera(tf.look_at([0.35, -0.35, 0.6], [0.0, 0.0, 0.0], [0, 0, 1]), 30.0, 20, 20)  # under the blocker
    return b.build(cam, RenderSettings(spp=4, shadow_rays=64))


def test_shadowed_shortcut_is_verified_too():
    """Case II: light through a small hole that the photons call shadowed. Unverified: too dark by far more
    than its noise; verified (auto and q = 1): within 4 SE of exact visibility, the correction measured."""
    scene = hole_scene()
    seeds = range(48)  # the map changes with the seed, and so does its bias: more seeds to see it
    exact = np.array([probvis.render(scene, seed=s).image.mean() for s in seeds])
    opts = {"photons": 1500, "neighbours": 8}
    with pytest.warns(UserWarning, match="the image is black"):  # the map calls the hole shadowed: nothing lit
        assert deviation(scene, exact, "occlusion-map", seeds, verify="off", **opts) < -4
    for extra in ({}, {"verify": "1"}, {"penumbra": "list"}):
        assert abs(deviation(scene, exact, "occlusion-map", seeds, **opts, **extra)) < 4, extra
    r = probvis.render(scene, seed=1, visibility="occlusion-map", visibility_options=opts)
    shadowed = r.stats["estimator"]["verification"]["shadowed"]
    assert shadowed["pairs"] > 0 and shadowed["verified_segments"] > 0 and shadowed["mismatch_mean"] > 0
