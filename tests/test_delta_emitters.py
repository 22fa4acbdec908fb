"""Point and spot lights against Mitsuba 3 (scalar_rgb), and the occlusion map and probabilistic visibility
staying unbiased with them (photons leave a point uniformly, a spot within its cone)."""
import re

import numpy as np
import pytest

import probvis
from probvis import ProbvisError
from tests.conftest import assert_matches_mitsuba, sensor, write_scene

GROUND = """
    <shape type="rectangle"><transform name="to_world"><scale value="2"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.6, 0.5"/></bsdf></shape>
    <shape type="cube"><transform name="to_world"><scale x="0.25" y="0.4" z="0.3"/>
        <rotate z="1" angle="30"/><translate x="-0.3" y="0.2" z="0.3"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.6, 0.3"/></bsdf></shape>"""
LIGHTS = GROUND + """
    <emitter type="point"><point name="position" x="0.4" y="-0.2" z="1.2"/><rgb name="intensity" value="3, 2.5, 2"/>
    </emitter>
    <emitter type="point"><transform name="to_world"><translate x="-1" y="0.5" z="0.8"/></transform>
        <rgb name="intensity" value="0.5, 0.8, 1.5"/></emitter>
    <emitter type="spot"><transform name="to_world"><lookat origin="0.8, 0.9, 1.5" target="0.2, 0.1, 0"/></transform>
        <rgb name="intensity" value="6"/><float name="cutoff_angle" value="25"/><float name="beam_width" value="12"/>
    </emitter>"""


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory):
    d = tmp_path_factory.mktemp("delta")
    return write_scene(d / "lights.xml", sensor(origin="0.3, -2.8, 1.7", target="0, 0, 0.3", up="0, 0, 1", fov=45,
                                                spp="$spp", w=40, h=32, sr=1) + LIGHTS, '<default name="spp" value="16"/>')


def test_point_and_spot_lights_match_mitsuba(scene_file):
    """At one emitter sample per camera sample: Mitsuba 3.9's `direct` integrator gives each delta-light sample
    full weight whatever `emitter_samples` is (its images are emitter_samples times too bright there), where
    probvis averages the samples as for area lights (docs/decisions.md)."""
    assert_matches_mitsuba(scene_file, shadow_rays=1)


def test_a_beam_wider_than_the_cutoff_matches_mitsuba(tmp_path, scene_file):
    """Mitsuba renders a spot whose beam_width exceeds its cutoff_angle at full intensity up to the cutoff; probvis
    refused it."""
    wide = tmp_path / "wide.xml"
    wide.write_text(scene_file.read_text().replace('name="beam_width" value="12"', 'name="beam_width" value="40"'))
    assert 'value="40"' in wide.read_text()
    assert_matches_mitsuba(wide, shadow_rays=1)


@pytest.mark.parametrize("visibility, options", [
    ("occlusion-map", {"photons": 20000}),
    ("occlusion-map", {"photons": 20000, "penumbra": "list"}),
    ("probvis", {"photons": 20000, "estimator": "shifted"}),
])
def test_occlusion_map_with_point_lights_is_unbiased(scene_file, visibility, options):
    """Same seeds, same camera samples: the per-seed difference from exact visibility averages to zero."""
    scene = probvis.load_scene(scene_file)

    def mean(seed, **vis):
        return probvis.render(scene, spp=2, shadow_rays=2, seed=seed, **vis).image.mean()

    diff = np.array([mean(s, visibility=visibility, visibility_options=options) - mean(s) for s in range(16)])
    assert abs(diff.mean()) < 4 * np.std(diff, ddof=1) / np.sqrt(len(diff))
    r = probvis.render(scene, spp=2, shadow_rays=2, visibility=visibility, visibility_options=options)
    assert r.stats["estimator"]["photons"] > 0 and r.stats["cases"]["lit"]["count"] > 0


@pytest.mark.parametrize("spot, message", [
    ('<float name="cutoff_angle" value="0"/>', "cutoff_angle must be in [0.001, 90]"),
    ('<float name="cutoff_angle" value="95"/>', "cutoff_angle 95: a spot wider than a hemisphere (above 90 "
                                                "degrees), which Mitsuba renders, is not supported"),
    ('<float name="cutoff_angle" value="20"/><float name="beam_width" value="-1"/>', "beam_width must be at least 0"),
])
def test_bad_spot_lights_are_named(tmp_path, spot, message):
    body = sensor() + f"""<shape type="rectangle"/><emitter type="spot">{spot}</emitter>"""
    with pytest.raises(ProbvisError, match=r"s.xml:\d+: <emitter>: " + re.escape(message)):
        probvis.load_scene(write_scene(tmp_path / "s.xml", body))


SUN = GROUND + """
    <emitter type="directional"><vector name="direction" x="0.4" y="0.6" z="-1"/>
        <rgb name="irradiance" value="2, 1.8, 1.5"/></emitter>"""


def test_a_directional_light_s_to_world_scale_scales_it_as_in_mitsuba(tmp_path):
    """Mitsuba lights along to_world's z axis without normalising it: a scale of 2 along the light's own z doubles
    its light (the other axes change nothing); probvis took only the direction, half Mitsuba's image."""
    def scene(scale):
        sun = GROUND + f"""
    <emitter type="directional"><transform name="to_world">{scale}<lookat origin="0, 0, 0" target="0.4, 0.6, -1"/>
        </transform><rgb name="irradiance" value="2, 1.8, 1.5"/></emitter>"""
        return write_scene(tmp_path / f"sun{len(scale)}.xml", sensor(origin="0.3, -2.8, 1.7", target="0, 0, 0.3",
                                                                    up="0, 0, 1", fov=45, spp="$spp", w=40, h=32,
                                                                    sr=1) + sun, '<default name="spp" value="16"/>')
    scaled = scene('<scale x="3" y="0.5" z="2"/>')
    plain = probvis.render(scene(""), spp=2, shadow_rays=1, seed=3).image
    np.testing.assert_allclose(probvis.render(scaled, spp=2, shadow_rays=1, seed=3).image, 2 * plain, rtol=1e-12)
    with pytest.raises(ProbvisError, match="irradiance times the length of to_world's z axis"):
        probvis.load_scene(scene('<scale value="1e60"/>'))
    assert_matches_mitsuba(scaled, shadow_rays=1)


def test_directional_light_matches_mitsuba_and_keeps_the_map_unbiased(tmp_path):
    path = write_scene(tmp_path / "sun.xml", sensor(origin="0.3, -2.8, 1.7", target="0, 0, 0.3", up="0, 0, 1",
                                                     fov=45, spp="$spp", w=40, h=32, sr=1) + SUN,
                       '<default name="spp" value="16"/>')
    assert_matches_mitsuba(path, shadow_rays=1)
    scene = probvis.load_scene(path)

    def mean(seed, **vis):
        return probvis.render(scene, spp=2, shadow_rays=2, seed=seed, **vis).image.mean()

    for options in ({"photons": 20000}, {"photons": 20000, "penumbra": "list", "adaptive_photons": True}):
        diff = np.array([mean(s, visibility="occlusion-map", visibility_options=options) - mean(s)
                         for s in range(16)])
        # a directional light has no emitter-sampling noise: where the map is right the images agree to rounding
        assert abs(diff.mean()) < 4 * np.std(diff, ddof=1) / np.sqrt(len(diff)) + 1e-12, options
    r = probvis.render(scene, spp=2, shadow_rays=2, visibility="occlusion-map", visibility_options={"photons": 20000})
    assert r.stats["cases"]["lit"]["count"] > 0 and r.stats["cases"]["shadowed"]["count"] > 0


def test_info_names_each_emitter_s_kind_and_quantity(tmp_path, capsys):
    """`probvis info`: a point or spot light's intensity, a directional light's irradiance, an environment's
    scale and map, and an area only for area lights (null in JSON)."""
    import json

    from probvis.cli import main
    path = write_scene(tmp_path / "all.xml", sensor(origin="0, -3, 1", target="0, 0, 0", up="0, 0, 1", fov=45,
                                                    spp="1", w=8, h=8, sr=1) + LIGHTS + """
    <emitter type="directional"><vector name="direction" x="0.4" y="0.6" z="-1"/><rgb name="irradiance" value="2"/>
    </emitter>
    <emitter type="constant"><rgb name="radiance" value="0.1"/></emitter>
    <shape type="rectangle"><transform name="to_world"><translate z="2"/></transform>
        <emitter type="area"><rgb name="radiance" value="4"/></emitter></shape>""")
    assert main(["info", str(path), "--json"]) == 0
    emitters = json.loads(capsys.readouterr().out)["emitters"]
    kinds = [(e["kind"], next(k for k in ("radiance", "intensity", "irradiance", "scale") if k in e), e["area"])
             for e in emitters]
    assert sorted(kinds, key=str) == sorted([("point", "intensity", None), ("point", "intensity", None),
                                             ("spot", "intensity", None), ("directional", "irradiance", None),
                                             ("environment", "scale", None), ("area", "radiance", 4.0)], key=str)
    assert main(["info", str(path)]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("emitter")]
    assert any("spot: intensity [6.0, 6.0, 6.0], power" in ln for ln in lines)
    assert sum("area " in ln for ln in lines) == 1
