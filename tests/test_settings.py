import warnings

import numpy as np
import pytest

import probvis
from probvis import ProbvisError, RenderSettings
from probvis.settings import MAX_SEED, parse_float, parse_int
from probvis.visibility import BUILTIN


@pytest.mark.parametrize("changes, message", [
    ({"spp": "a"}, "spp must be a whole number from 1 to 1048576, got 'a'"),
    ({"spp": "4"}, "spp must be a whole number from 1 to 1048576, got '4'"),
    ({"spp": float("nan")}, "spp must be a whole number from 1 to 1048576, got nan"),
    ({"spp": float("inf")}, "spp must be a whole number from 1 to 1048576, got inf"),
    ({"spp": [1]}, "spp must be a whole number from 1 to 1048576, got [1]"),
    ({"spp": None}, "spp must be a whole number from 1 to 1048576, got None"),
    ({"threads": "2"}, "threads must be a positive whole number, got '2'"),
    ({"seed": 1.5}, "seed must be a whole number from 0"),
    ({"threads": -1}, "threads must be a positive whole number, got -1"),
    ({"filter_importance": "no"}, "filter_importance must be True or False, got 'no'"),
])
def test_settings_of_the_wrong_type_are_named(changes, message):
    """Raw ValueError, OverflowError and TypeError from int() before; the error names the setting and value, where
    the settings are made (not at a later render)."""
    makers = [lambda: RenderSettings(**changes)]
    if None not in changes.values():  # replace() keeps a setting given as None
        makers.append(lambda: RenderSettings().replace(**changes))
    for make in makers:
        with pytest.raises(ProbvisError, match=message.replace("[", r"\[").replace("]", r"\]")):
            make()


def test_whole_floats_are_whole_numbers():
    assert RenderSettings(spp=4.0, threads=2.0).validate().spp == 4


@pytest.mark.parametrize("text", ["1_6", "\u0661\u0666", "0x10", "", " ", "1 6", "1e3"])
def test_whole_numbers_are_read_in_c_syntax_only(text):
    with pytest.raises(ValueError):
        parse_int(text)


@pytest.mark.parametrize("text, value", [("16", 16), (" -3 ", -3), ("+7", 7)])
def test_whole_numbers_in_c_syntax_are_read(text, value):
    assert parse_int(text) == value


@pytest.mark.parametrize("text", ["0_5", "\u0660.5", "1e", ".", "0x1p3", "infinit"])
def test_numbers_are_read_in_c_syntax_only(text):
    with pytest.raises(ValueError):
        parse_float(text)


@pytest.mark.parametrize("text, value", [("0.5", 0.5), ("-.5e-3", -0.5e-3), ("5.", 5.0), ("1E+2", 100.0)])
def test_numbers_in_c_syntax_are_read(text, value):
    assert parse_float(text) == value


def test_replace_names_a_setting_it_does_not_have():
    """`replace` is the settings' own validated copy: an unknown name is refused naming it and the settings
    (dataclasses.replace's TypeError came from deep inside)."""
    with pytest.raises(ProbvisError, match=r"RenderSettings has no setting 'sp' \(its settings: spp, shadow_rays"):
        RenderSettings().replace(sp=3)
    with pytest.raises(ProbvisError, match=r"RenderSettings\(\): got an unexpected keyword argument 'sp' \(did you "
                                           r"mean spp=\?\)"):
        RenderSettings(sp=3)
    with pytest.raises(ProbvisError, match=r"RenderSettings\(\): too many positional arguments"):
        RenderSettings(1, 2, 3, None, False, 6)


@pytest.mark.parametrize("name", sorted(BUILTIN))
def test_every_built_in_estimator_renders_at_the_largest_seeds(name):
    """Seeds run to 2^63 - 1 for every estimator, its pilots included: nee++'s and cache-cv's pilot added 2^40 to
    the seed, past the kernels' signed 64 bits (an OverflowError traceback for the top 2^40 seeds)."""
    for seed in (MAX_SEED, MAX_SEED - (1 << 40) + 1):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # proxy: no mesh heavy enough
            r = probvis.render("quad-shadow", resolution=(8, 8), spp=1, shadow_rays=2, seed=seed, threads=1,
                               visibility=name)
        assert np.isfinite(r.image).all() and r.image.max() > 0
