"""Estimators from outside probvis: the worked example of docs/writing-an-estimator.md, loaded by file, by
module and through the entry-point group, through the CLI, the Python API and `probvis experiment`."""
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import probvis
from probvis.errors import ProbvisError
from probvis.visibility import available_names, estimator_class

DOC = Path(__file__).resolve().parents[1] / "docs" / "writing-an-estimator.md"


def example_source():
    """The first Python code block of the guide."""
    return re.search(r"```python\n(.*?)```", DOC.read_text(), re.S).group(1)


@pytest.fixture
def roulette(tmp_path):
    path = tmp_path / "roulette.py"
    path.write_text(example_source())
    return path


def run_cli(*args, cwd=None, env=None):
    return subprocess.run([sys.executable, "-m", "probvis.cli", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=600, env=env)


def test_the_guide_s_estimator_renders_through_the_cli(roulette, tmp_path):
    out = tmp_path / "r.exr"
    stats = tmp_path / "r.json"
    r = run_cli("render", "quad-shadow", "-D", "res=12", "--spp", "2", "--visibility", f"{roulette}:RouletteVisibility",
                "--q", "0.25", "-o", out, "--stats", stats, "-q")
    assert r.returncode == 0, r.stderr
    s = json.loads(stats.read_text())
    assert out.is_file() and s["visibility"] == {"name": "roulette", "q": 0.25}
    assert "trace" in s["estimator"]["seconds"]
    by_module = run_cli("render", "quad-shadow", "-D", "res=12", "--visibility", "roulette:RouletteVisibility",
                        "--q", "0.5", "-o", tmp_path / "m.exr", "-q", cwd=tmp_path)
    assert by_module.returncode == 0, by_module.stderr
    listed = run_cli("estimators", f"{roulette}:RouletteVisibility")
    assert listed.returncode == 0 and "--q" in listed.stdout and "traced" in listed.stdout


def test_flags_are_those_the_estimator_declares(roulette, tmp_path):
    r = run_cli("render", "quad-shadow", "--visibility", f"{roulette}:RouletteVisibility", "--photons", "10",
                "-o", tmp_path / "x.exr")
    assert r.returncode == 2 and not (tmp_path / "x.exr").exists()
    assert r.stderr.strip() == ("probvis: error: --photons does not apply to --visibility roulette (it is an "
                                "option of occlusion-map, probvis; see `probvis estimators`)")
    bad = run_cli("render", "quad-shadow", "--visibility", f"{roulette}:RouletteVisibility", "--q", "2")
    assert bad.returncode == 2 and "q must be from 0.001 to 1" in bad.stderr and "Traceback" not in bad.stderr


def test_the_guide_s_estimator_is_unbiased_against_exact_visibility(roulette):
    """Same seeds, same segments: the per-seed difference from exact visibility averages to zero within 4 SE,
    and it does not for a deliberately wrong weight (the test can fail)."""
    spec = f"{roulette}:RouletteVisibility"

    def mean(seed, **vis):
        return probvis.render("quad-shadow", spp=2, shadow_rays=4, seed=seed, defines={"res": 12}, **vis).image.mean()

    exact = np.array([mean(s) for s in range(30)])
    diff = np.array([mean(s, visibility=spec, visibility_options={"q": 0.3}) for s in range(30)]) - exact
    se = np.std(diff, ddof=1) / np.sqrt(len(diff))
    assert se > 0 and abs(diff.mean()) < 4 * se
    cls = estimator_class(spec)

    class Heavy(cls):  # the weight 1/q forgotten: biased low
        def evaluate(self, query):
            res = super().evaluate(query)
            res.value *= self.params.q
            return res

    heavy = np.array([mean(s, visibility=Heavy, visibility_options={"q": 0.3}) for s in range(30)]) - exact
    assert abs(heavy.mean()) > 4 * np.std(heavy, ddof=1) / np.sqrt(len(heavy))


def test_the_guide_s_estimator_runs_in_an_experiment(roulette, tmp_path):
    from probvis.experiments import experiment, load_experiment

    study = tmp_path / "study.toml"
    study.write_text("""name = "plugin"
spp = 1
shadow_rays = [1, 2]
resolution = [8, 8]
[reference]
spp = 4
shadow_rays = 4
[[scenes]]
name = "q"
source = "quad-shadow"
[[methods]]
name = "exact"
visibility = "exact"
[[methods]]
name = "roulette"
visibility = "roulette.py:RouletteVisibility"
options = { q = 0.5 }
""")
    exp = load_experiment(study)
    assert exp.methods[1].visibility == f"{roulette}:RouletteVisibility"
    results, index, run = experiment(exp, tmp_path / "report", progress=False, log=lambda m: None)
    rows = [r for r in results.cells if r["method"] == "roulette"]
    assert len(rows) == 2 and all("trace" in r["seconds_phases"] for r in rows)
    assert index.is_file()
    bad = tmp_path / "bad.toml"
    bad.write_text(study.read_text().replace("q = 0.5", "q = 5"))
    with pytest.raises(ProbvisError, match=r"method 'roulette': q must be from 0.001 to 1"):
        load_experiment(bad)


def test_a_plugin_s_cache_key_changes_with_the_helpers_it_imports(tmp_path):
    """Only the plug-in's own file was hashed: an edit to a module it imports reused stale cached renders."""
    from probvis.experiments.runner import estimator_fingerprint

    (tmp_path / "helper.py").write_text("Q = 0.5\n")
    source = example_source().replace("import numpy as np", "import numpy as np\nimport helper", 1)
    (tmp_path / "uses.py").write_text(source)
    spec = f"{tmp_path / 'uses.py'}:RouletteVisibility"
    sys.path.insert(0, str(tmp_path))
    try:
        before = estimator_fingerprint(spec)
        assert estimator_fingerprint(spec) == before
        (tmp_path / "helper.py").write_text("Q = 0.25\n")
        assert estimator_fingerprint(spec) != before
    finally:
        sys.path.remove(str(tmp_path))
    assert estimator_fingerprint("exact") == ""


def test_installed_estimators_load_through_the_entry_point_group(roulette, tmp_path, monkeypatch):
    site = tmp_path / "site"
    (site / "roulette_pkg").mkdir(parents=True)
    (site / "roulette_pkg" / "__init__.py").write_text(example_source())
    dist = site / "roulette_pkg-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: roulette-pkg\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[probvis.visibility]\nroulette = roulette_pkg:RouletteVisibility\n")
    monkeypatch.syspath_prepend(str(site))
    assert "roulette" in available_names()
    cls = estimator_class("roulette")
    assert cls.name == "roulette" and [o.name for o in cls.options] == ["q"]
    r = probvis.render("quad-shadow", spp=1, shadow_rays=1, defines={"res": 8}, visibility="roulette",
                       visibility_options={"q": 1.0})
    exact = probvis.render("quad-shadow", spp=1, shadow_rays=1, defines={"res": 8})
    np.testing.assert_array_equal(r.image, exact.image)  # q = 1 traces every segment: exact visibility


@pytest.mark.parametrize("spec, message", [
    ("nowhere_module:Thing", "cannot import 'nowhere_module'"),
    ("probvis.settings:RenderSettings", "is not a probvis.visibility.VisibilityEstimator subclass"),
    ("magic", "unknown visibility 'magic'"),
    (".hidden:X", "'.hidden' is neither a module name (package.module) nor a Python file (.py)"),  # was a TypeError
    ("./x.xml:P", "'./x.xml' is neither a module name"),
    # was "cannot import 'exact': No module named 'exact'"
    ("exact:shells=off", "'exact:shells=off' is not an estimator: 'exact' is a built-in one, whose options are flags"),
])
def test_bad_estimator_names_are_one_line_errors(spec, message):
    with pytest.raises(ProbvisError, match=re.escape(message)):
        estimator_class(spec)


def test_a_package_beside_the_user_is_a_module_name(tmp_path, monkeypatch):
    """A package folder in the working directory names a module (`pkgplugin:Mine`), not a file of another kind."""
    (tmp_path / "pkgplugin").mkdir()
    (tmp_path / "pkgplugin" / "__init__.py").write_text(
        "from probvis.visibility.exact import ExactVisibility\n\n\nclass Mine(ExactVisibility):\n    name = 'mine'\n")
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    assert estimator_class("pkgplugin:Mine").name == "mine"


def test_a_plugin_path_that_is_a_folder_is_named_a_folder(tmp_path):
    (tmp_path / "pdir.py").mkdir()
    with pytest.raises(ProbvisError, match=re.escape(f"{tmp_path / 'pdir.py'} is a folder, not a Python file")):
        estimator_class(f"{tmp_path / 'pdir.py'}:P")
    with pytest.raises(ProbvisError, match=re.escape(f"no file {tmp_path / 'none.py'}")):
        estimator_class(f"{tmp_path / 'none.py'}:P")
    os.mkfifo(tmp_path / "fifo.py")
    with pytest.raises(ProbvisError, match=re.escape(f"{tmp_path / 'fifo.py'} is not a regular file")):
        estimator_class(f"{tmp_path / 'fifo.py'}:P")


class _Broken(probvis.visibility.VisibilityEstimator):
    """An estimator whose `evaluate` misbehaves as `mode` says."""

    name = "broken"
    summary = "returns what it should not"
    mode = "nan"

    def evaluate(self, query):
        n = len(query.origin)
        zeros, ones = np.zeros(n, np.int64), np.ones(n)
        value, counts, aovs = {"nan": np.full(n, np.nan), "short": np.ones(max(n - 1, 0)), "huge": np.full(n, 1e300),
                               "complex": ones + 1j, "masked": np.ma.masked_less(ones, 2.0)}.get(self.mode, ones), \
            zeros, {}
        if self.mode == "tuple":
            return (np.ones(n), zeros, zeros)
        if self.mode in ("negative tests", "fractional tests"):
            counts = zeros - 3 if self.mode == "negative tests" else np.full(n, 0.5)
        if self.mode == "undeclared aov":
            aovs = {"foo": ones}
        if self.mode == "huge aov":
            aovs = {"bar": np.full(n, 1e308)}
        if self.mode == "raises":
            raise ZeroDivisionError("oops")
        if self.mode == "out of memory":
            raise MemoryError
        if self.mode == "generator exit":
            raise GeneratorExit
        if self.mode == "unprintable":
            raise _Unprintable()
        if self.mode == "undeclared phase":
            with self.timed("nope"):
                pass
        return probvis.visibility.VisibilityResult(value, zeros, counts, aovs)


@pytest.mark.parametrize("mode, message", [
    ("nan", r"returned \d+ values that are not finite or beyond"),
    ("huge", r"returned \d+ values that are not finite or beyond ±1e\+12"),
    ("complex", r"returned value of shape \(\d+,\) \(complex128\)"),
    ("short", "returned value of shape"),
    ("tuple", "returned a tuple, not a VisibilityResult"),
    # its mask was dropped by the checks and the kernel refused the array: "a bug in the estimator"
    ("masked", r"returned value as a masked array \(numpy.ma\): give a plain array, the masked entries filled"),
    ("negative tests", "returned triangle_tests that are not whole numbers >= 0"),
    ("fractional tests", "returned triangle_tests that are not whole numbers >= 0"),
    ("undeclared aov", "returned AOV 'foo', which the class does not declare"),
    # each 1e308 was finite, the pixels' sums inf with exit 0
    ("huge aov", r"returned AOV 'bar' values beyond ±1e\+100 \(up to 1e\+308\): the pixels' sums would overflow"),
    # a declared AOV never returned was a silent zero image
    ("missing aov", "returned no AOV 'bar', which the class declares in `aovs`: return one number per segment"),
])
def test_misbehaving_estimators_are_named_not_rendered(mode, message):
    declared = {"aovs": (probvis.visibility.Aov("bar", "declared, never returned"),)} \
        if mode in ("missing aov", "huge aov") else {}
    cls = type(f"Broken_{mode.replace(' ', '_')}", (_Broken,), {"mode": mode, **declared})
    with pytest.raises(ProbvisError, match=rf"visibility 'broken' \(.*{cls.__name__}\): evaluate {message}"):
        probvis.render("quad-shadow", spp=1, visibility=cls)


@pytest.mark.parametrize("mode, message", [
    ("raises", r"raised ZeroDivisionError in the render \(.*\): oops \(a bug in the estimator; rerunning will not help\)"),
    ("undeclared phase", r"times phase 'nope', which it does not declare in `phases`"),
    ("out of memory", r"ran out of memory in the render \(.*\): an allocation of its own"),
    ("generator exit", r"raised GeneratorExit in the render"),
    # an exception whose own __str__ raises was a traceback from formatting the error line
    ("unprintable", r"raised _Unprintable in the render \(.*\): <_Unprintable: its str\(\) failed>"),
])
def test_an_estimator_that_raises_is_named(mode, message):
    cls = type(f"Broken_{mode.replace(' ', '_')}", (_Broken,), {"mode": mode})
    with pytest.raises(ProbvisError, match=rf"visibility 'broken' \(.*{cls.__name__}\).*{message}"):
        probvis.render("quad-shadow", spp=1, visibility=cls)


class _Unprintable(Exception):
    def __str__(self):
        raise ValueError("str")


class _Exact(probvis.visibility.VisibilityEstimator):
    """Exact visibility through the staged interface; subclasses break one other method."""

    name = "exact-plugin"
    summary = "exact"

    def evaluate(self, query):
        occ, node, tri = probvis.accel.occluded_segments(self.bvh, query.origin, query.direction, query.tmax,
                                                          query.point)
        return probvis.visibility.VisibilityResult(1.0 - occ, node, tri)


def _no_super(self, scene, bvh, emitters, settings, integrator):
    pass


def _scales_triangles(self, scene, bvh, emitters, settings, integrator):
    _Exact.prepare(self, scene, bvh, emitters, settings, integrator)
    integrator.scene_arrays.triangles[:] *= 5.0  # the kernels' arrays, which are the caller's


def _nested(depth):
    out = {}
    for _ in range(depth):
        out = {"a": out}
    return out


def _raise(*args, **kwargs):
    raise RuntimeError("inner")


@pytest.mark.parametrize("methods, message", [
    ({"__init__": _raise}, "raised RuntimeError in __init__: inner"),
    ({"prepare": _raise}, "raised RuntimeError in the render"),
    ({"prepare": _no_super}, "raised AttributeError in the render"),
    ({"stats": _raise}, "raised RuntimeError in stats: inner"),
    ({"stats": lambda self: {"ratio": float("nan")}}, "stats\\(\\) returned a value JSON cannot hold"),
    ({"stats": lambda self: {"ids": np.arange(3)}}, "stats\\(\\) returned a value JSON cannot hold"),
    ({"memory_estimate": lambda self, *a: {"x": "lots"}}, "memory_estimate\\(\\) must return a dict of byte counts"),
    ({"memory_estimate": lambda self, *a: {"x": -10 ** 12}}, "memory_estimate\\(\\) must return a dict of byte counts"),
    ({"classify": lambda self, points: np.zeros(3, np.int8)}, "classify returned int8 of shape \\(3,\\)"),
    # a code out of range was named as a wrong dtype or shape
    ({"classify": lambda self, points: np.full((len(points.position), 1), 9, np.int8)},
     "classify returned \\d+ values that are no case, such as 9: use probvis.cases' CASE_UNKNOWN"),
    ({"evaluate": lambda self, query: sys.exit(5)}, "raised SystemExit in the render .*: 5"),
    ({"evaluate": lambda self, q: probvis.visibility.VisibilityResult(np.ones(len(q.tmax)), np.zeros(len(q.tmax)),
                                                                      np.full(len(q.tmax), 2 ** 62))},
     "returned triangle_tests above 2,147,483,648 for one segment"),
    ({"stats": lambda self: [1]}, "stats\\(\\) returned a list, not a dict"),
    ({"evaluate": lambda self, q: probvis.visibility.VisibilityResult(np.ones(len(q.tmax)), np.zeros(len(q.tmax)),
                                                                      np.zeros(len(q.tmax)), [])},
     "returned aovs as a list: give a dict"),  # probvis's own check raised an AttributeError (sweep 42)
    ({"memory_bytes": lambda self: {"x": "lots"}}, "memory_bytes\\(\\) must return a dict of byte counts"),
    ({"prepare": lambda self, *a: open("no-such-weights.dat")}, "raised FileNotFoundError in the render"),
    ({"prepare": _scales_triangles}, "changed the arrays of the scene, its emitters or its BVH"),
    ({"memory_estimate": lambda self, *a: {"film": 0, "scene": 0}}, "memory_estimate\\(\\) names film, scene, which"),
    ({"stats": lambda self: {**_Exact.stats(self), "tests": {"proxy": {"node": "many"}}}},
     "stats\\(\\)\\['tests'\\] must map a geometry to its counts"),
    ({"stats": lambda self: {**_Exact.stats(self), "seconds": {"x": -1.0}}}, "stats\\(\\)\\['seconds'\\] must map"),
    ({"stats": lambda self: {**_Exact.stats(self), "biased": "no"}}, "stats\\(\\)\\['biased'\\] must be True or"),
    ({"stats": lambda self: _nested(3000)}, "stats\\(\\) returned a value JSON cannot hold \\(RecursionError"),
    ({"render_path": lambda self: probvis.visibility.RenderPath.OWN_KERNEL,
      "shade": lambda self, b: self.integrator.shade_exact(b)._replace(radiance=np.full((len(b.keys), 3), np.nan))},
     "shade\\(\\) returned radiance of shape"),
    ({"render_path": lambda self: probvis.visibility.RenderPath.OWN_KERNEL,
      "shade": lambda self, b: tuple(self.integrator.shade_exact(b))}, "shade\\(\\) returned tuple, not a ShadedBatch"),
    ({"aovs": (probvis.visibility.Aov("bar", "declared, never returned"),),
      "render_path": lambda self: probvis.visibility.RenderPath.OWN_KERNEL,
      "shade": lambda self, b: self.integrator.shade_exact(b)}, "shade\\(\\) returned no AOV 'bar', which the class "
     "declares in `aovs`: return one number per pixel"),
])
def test_a_plugin_s_every_method_is_checked(methods, message):
    cls = type("Faulty", (_Exact,), methods)
    with pytest.raises(ProbvisError, match=rf"visibility 'exact-plugin' \(.*Faulty\).*{message}"):
        probvis.render("quad-shadow", spp=1, defines={"res": 8}, visibility=cls)
    assert probvis.render("quad-shadow", spp=1, defines={"res": 8}, visibility=_Exact).image.mean() > 0


def test_numpy_byte_counts_are_byte_counts():
    """`memory_bytes()` of NumPy integers (a sum of arrays' nbytes) passed the check, then failed the render as
    "stats() returned a value JSON cannot hold" though the plug-in had no stats() (sweep 42)."""
    cls = type("NumpyBytes", (_Exact,), {"memory_bytes": lambda self: {"table": np.int64(4096)}})
    stats = probvis.render("quad-shadow", spp=1, defines={"res": 8}, visibility=cls).stats
    assert stats["estimator"]["memory_bytes"] == {"table": 4096}
    assert type(stats["estimator"]["memory_bytes"]["table"]) is int


def test_a_plugin_s_own_memory_is_named_with_it():
    """A plug-in's part of an estimate beyond the machine was named only by its key ('mine'), with "lower the
    settings"."""
    cls = type("Hungry", (_Exact,), {"memory_estimate": lambda self, *a: {"mine": 2 ** 62}})
    with pytest.raises(ProbvisError, match=r"needs about .* \(visibility 'exact-plugin': mine .* GiB\) but .* are "
                       r"available: lower the options of visibility 'exact-plugin'"):
        probvis.render("quad-shadow", spp=1, defines={"res": 8}, visibility=cls)


@pytest.mark.parametrize("options, message", [
    ((probvis.visibility.Option("spp", int, 1, "clash"),), "option 'spp' (--spp) clashes with probvis's own --spp"),
    ((probvis.visibility.Option("q", float, 0.5, "a"), probvis.visibility.Option("q", float, 0.5, "b")),
     "declares option 'q' twice"),
    ((probvis.visibility.Option("p", float, 5.0, "above its maximum", minimum=0.0, maximum=1.0),),
     "the default of option 'p' is invalid: p must be from 0 to 1, got 5.0"),
    ((probvis.visibility.Option("kind", str, "c", "not a choice", choices=("a", "b")),),
     "the default of option 'kind' is invalid: kind must be one of a, b, got 'c'"),
    ((probvis.visibility.Option("k", list, [1], "a list"),), "option 'k' has type 'list', which an option cannot take"),
    ((probvis.visibility.Option("shadowless", bool, "false", "a bool as text"),),
     "the default of option 'shadowless' is 'false' (type str), not a value of the option's type: write False"),
    ((probvis.visibility.Option("n", int, "3", "an int as text"),), "is '3' (type str), not a value of the option's type: "
     "write 3"),
    ((probvis.visibility.Option("n", int, 3.0, "an int as a float"),), "is 3.0 (type float), not a value of the option's"),
    ((probvis.visibility.Option("t", tuple, "1,2", "a tuple as text", count=2),), "write (1.0, 2.0)"),
    ((probvis.visibility.Option("s", str, 5, "a number for a text"),), "is 5 (type int), not a value of the option's type: "
     "write '5'"),
    ((probvis.visibility.Option("s", probvis.visibility.Switch, "true", "a switch as true"),), "write 'on'"),
    # was "its check raised OverflowError", with no check declared
    ((probvis.visibility.Option("k", float, 10 ** 400, "beyond a float"),), "the default of option 'k' is invalid: k "
     "expects a finite number, got 1000"),
    ((probvis.visibility.Option("t", tuple, (1.0, 2.0), "no count"),), "option 't' is a tuple and needs count"),
    ((probvis.visibility.Option("k", int, 1, "raises", check=lambda v: 1 / 0),),
     "the default of option 'k' is invalid: k: its check raised ZeroDivisionError on 1: division by zero (a bug"),
    # choices and ranges a parse could not use: a traceback, a valid value refused, a substring taken for a choice
    ((probvis.visibility.Option("k", int, None, "int choices", choices=(1, 2)),),
     "option 'k': choices must be a tuple of words for a str option, got (1, 2) for a int option"),
    ((probvis.visibility.Option("k", str, "a", "choices as one string", choices="abc"),),
     "option 'k': choices must be a tuple of words for a str option, got 'abc'"),
    ((probvis.visibility.Option("k", float, 1.0, "minimum as text", minimum="0"),),
     "option 'k': minimum must be a finite number for an int, float or tuple option, got '0'"),
    ((probvis.visibility.Option("k", float, None, "reversed", minimum=5, maximum=1),),
     "option 'k': minimum 5 is above maximum 1: no value would be accepted"),
    (probvis.visibility.Option("k", int, 1, "not in a tuple"), "options must be a tuple of Options"),
    (None, "options must be a tuple of Options, got None"),
    ((probvis.visibility.Option("x", bool, False, "a"), probvis.visibility.Option("no_x", int, 1, "b")),
     "options 'x' and 'no_x' both make the flag --no-x"),
    ((probvis.visibility.Option("a_b", int, 1, "a"), probvis.visibility.Option("a-b", int, 1, "b")),
     "option names are identifiers (letters, digits, '_'), got 'a-b'"),
    ((probvis.visibility.Option(5, int, 1, "a"),), "option names are identifiers (letters, digits, '_'), got 5"),
    ((probvis.visibility.Option("", int, 1, "a"),), "option names are identifiers (letters, digits, '_'), got ''"),
    ((probvis.visibility.Option("my opt", int, 1, "a"),), "got 'my opt'"),
    ((probvis.visibility.Option("k", int, 1, "red\x1b[31m"),), "option 'k': help must be one line of plain text"),
])
def test_a_plugin_s_options_are_checked_when_it_loads(options, message):
    cls = type("Declared", (_Exact,), {"options": options})
    with pytest.raises(ProbvisError, match=re.escape(message)):
        estimator_class(cls)


def _refuse(message):
    raise ProbvisError(message)


@pytest.mark.parametrize("check, value, message", [
    (lambda v: None if 10 // (v - 9) else None, "9",
     "k: its check raised ZeroDivisionError on '9': integer division or modulo by zero (a bug in the estimator's "
     "option check)"),
    (lambda v: v > 2, "3", "k: its check returned True on '3', not an error message (a string) or None"),
])
def test_a_plugin_s_option_check_that_fails_on_a_value_is_named(check, value, message):
    """A check that raised on a user's value was a traceback; one returning True for 'bad' read 'k True'. A check
    returning False (no problem) is taken as None."""
    cls = type("Checked", (_Exact,), {"options": (probvis.visibility.Option("k", int, 1, "checked", check=check),)})
    with pytest.raises(ProbvisError, match=re.escape(message)):
        estimator_class(cls)(k=value)
    assert estimator_class(cls)(k="1").params.k == 1


def test_a_plugin_s_option_check_may_refuse_in_its_own_words():
    """A check that raises ProbvisError refuses the value with its message, not as 'a bug in the check'."""
    check = probvis.visibility.Option("k", int, 1, "odd", check=lambda v: _refuse("k must be odd") if v % 2 == 0
                                      else None)
    with pytest.raises(ProbvisError, match=r"^k must be odd$"):
        estimator_class(type("Odd", (_Exact,), {"options": (check,)}))(k="4")


@pytest.mark.parametrize("declared, message", [
    ({"name": "exact"}, "name 'exact' is a built-in estimator's"),
    ({"name": 42}, "name must be one word"), ({"name": "has space"}, "name must be one word"),
    ({"phases": (probvis.visibility.Phase("p", "sometimes"),)}, "phase 'p' has stage 'sometimes'"),
    ({"aovs": (probvis.visibility.Aov("a", "h", "weird"),)}, "AOV 'a' has kind 'weird'"),
    ({"phases": "prepare"}, "phases must be a tuple of Phases, got 'prepare'"),
    ({"unbiased": "no"}, "unbiased must be True or False, got 'no'"),
    ({"summary": "line one\nline two\x1b[31mred"}, "summary must be one line of plain text"),
    ({"aovs": (probvis.visibility.Aov("cases", "the cases", kind="cases"),)}, "named 'cases', from the estimator's "
                                                                            "classify (got 'cases', no classify)"),
    ({"aovs": (probvis.visibility.Aov("triangle_tests", "clash"),)}, "AOV 'triangle_tests' is one of the film's own"),
    ({"aovs": (probvis.visibility.Aov("second_moment", "clash"),)}, "AOV 'second_moment' is one of the film's own"),
    ({"aovs": (probvis.visibility.Aov("a", "x"), probvis.visibility.Aov("a", "y"))}, "declares AOV 'a' twice"),
    ({"phases": (probvis.visibility.Phase("p", "batch"), probvis.visibility.Phase("p", "prepare"))},
     "declares phase 'p' twice"),
    ({"phases": (probvis.visibility.Phase("load", "prepare"),)}, "phase 'load' is one of probvis's own"),
    ({"phases": (probvis.visibility.Phase("render", "batch"),)}, "phase 'render' is one of probvis's own"),
    ({"phases": (probvis.visibility.Phase("a b", "batch"),)}, "phase names are identifiers"),
])
def test_a_plugin_s_name_phases_and_aovs_are_checked_when_it_loads(declared, message):
    with pytest.raises(ProbvisError, match=re.escape(message)):
        estimator_class(type("Declared", (_Exact,), declared))


def test_a_plugin_gets_the_scene_read_only():
    """A plug-in that writes the scene's arrays (reflectance zeroed in prepare) fails in its own code as its bug;
    the caller's Scene is unchanged for the next render (it was black with exact visibility)."""
    def zero(self, scene, bvh, emitters, settings, integrator):
        _Exact.prepare(self, scene, bvh, emitters, settings, integrator)
        scene.reflectance[:] = 0.0

    scene = probvis.load_scene("quad-shadow", res=8)
    before = probvis.render(scene, spp=1).image
    with pytest.raises(ProbvisError, match="raised ValueError in the render .*read-only"):
        probvis.render(scene, spp=1, visibility=type("Writes", (_Exact,), {"prepare": zero}))
    np.testing.assert_array_equal(probvis.render(scene, spp=1).image, before)
    assert before.mean() > 0 and scene.reflectance.flags.writeable


def test_a_plugin_file_that_raises_is_one_line_and_writes_nothing(tmp_path):
    (tmp_path / "ests.py").write_text("import numpy as np\nimport probvis\n\n\n"
                                      "class Raises(probvis.visibility.VisibilityEstimator):\n"
                                      "    name = 'raises'\n    summary = 'raises'\n\n"
                                      "    def evaluate(self, query):\n        raise ZeroDivisionError('oops')\n")
    (tmp_path / "exits.py").write_text("import sys\nsys.exit(3)\n")
    for spec, message in (("ests.py:Raises", "raised ZeroDivisionError in the render"),
                          ("exits.py:X", "cannot import 'exits.py': SystemExit: 3"),
                          ("ests.py:Nope", "'ests.py' defines no 'Nope'")):
        r = run_cli("render", "quad-shadow", "-D", "res=8", "--spp", "1", "--visibility", spec, "-o", "o.exr",
                    cwd=tmp_path)
        assert r.returncode != 0 and r.stderr.count("\n") == 1 and message in r.stderr, r.stderr
        assert not (tmp_path / "o.exr").exists()


def test_a_plugin_file_imports_the_modules_beside_it(tmp_path):
    """As `python sub/est.py` would: a plug-in file's own folder is where its imports are found too."""
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "helper_beside.py").write_text("FACTOR = 1.0\n")
    (tmp_path / "sub" / "est.py").write_text(
        "import numpy as np\nimport probvis\nfrom helper_beside import FACTOR\n\n\n"
        "class Exactish(probvis.visibility.VisibilityEstimator):\n    name = 'exactish'\n    summary = 'exact'\n\n"
        "    def evaluate(self, query):\n"
        "        occ, nodes, tris = probvis.accel.occluded_segments(self.bvh, query.origin, query.direction, "
        "query.tmax, query.point)\n"
        "        return probvis.visibility.VisibilityResult(FACTOR - occ, nodes, tris)\n")
    r = run_cli("render", "quad-shadow", "-D", "res=8", "--spp", "1", "--visibility", "sub/est.py:Exactish", "-o",
                "o.exr", "-q", cwd=tmp_path)
    assert r.returncode == 0 and (tmp_path / "o.exr").is_file(), r.stderr
    # `--visibility=~/...`: the shell leaves that ~ alone, probvis reads it as the home
    r = run_cli("render", "quad-shadow", "-D", "res=8", "--spp", "1", "--visibility=~/sub/est.py:Exactish", "-o",
                "p.exr", "-q", cwd=tmp_path, env={**os.environ, "HOME": str(tmp_path)})
    assert r.returncode == 0 and (tmp_path / "p.exr").is_file(), r.stderr
    r = run_cli("render", "quad-shadow", "--visibility=~nosuchuser0/est.py:Exactish", "-o", "q.exr", cwd=tmp_path)
    assert r.returncode == 2 and r.stderr == ("probvis: error: --visibility: '~nosuchuser0/est.py' names the home of a "
                                              "user this machine does not know\n"), r.stderr


def test_an_estimator_without_evaluate_is_refused():
    class Hollow(probvis.visibility.VisibilityEstimator):
        name = "hollow"
        summary = "nothing"

    with pytest.raises(ProbvisError, match="Hollow does not implement evaluate"):
        probvis.render("quad-shadow", spp=1, visibility=Hollow)


def test_a_plugin_s_float16_or_float32_values_render_as_float64():
    """float16 values were a NotImplementedError inside the kernels, blamed on the estimator."""
    class Half(_Exact):
        name = "half"

        def evaluate(self, query):
            res = super().evaluate(query)
            return probvis.visibility.VisibilityResult(res.value.astype(np.float16), res.node_tests,
                                                       res.triangle_tests)

    kwargs = dict(resolution=(8, 8), spp=1, shadow_rays=2, threads=1, progress=False)
    half = probvis.render("quad-shadow", visibility=estimator_class(Half), **kwargs)
    exact = probvis.render("quad-shadow", visibility="exact", **kwargs)
    np.testing.assert_array_equal(half.image, exact.image)


def test_a_plugin_that_changes_folder_does_not_move_the_outputs(tmp_path, monkeypatch):
    """The image went to the plug-in's folder ("/out.exr") while the summary said "wrote out.exr"."""
    (tmp_path / "ests.py").write_text(
        "import os\nimport probvis\n\n\nclass Moves(probvis.visibility.VisibilityEstimator):\n"
        "    name = 'moves'\n\n    def prepare(self, *args):\n        super().prepare(*args)\n"
        "        os.chdir(os.path.dirname(os.getcwd()))\n\n    def evaluate(self, query):\n"
        "        return probvis.visibility.VisibilityResult(query.tmax * 0 + 1.0, query.tmax * 0, query.tmax * 0)\n")
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    from probvis.cli import main

    assert main(["render", "quad-shadow", "-D", "res=8", "--spp", "1", "-q", "--visibility",
                 str(tmp_path / "ests.py") + ":Moves", "-o", "out.exr"]) == 0
    assert (work / "out.exr").is_file() and not (tmp_path / "out.exr").exists()


def test_numpy_values_in_an_option_declaration_are_python_numbers(tmp_path):
    """A plug-in's np.float32 default broke `estimators --json` (a traceback) and `render --stats` (after the
    render)."""
    from probvis.visibility.base import Option

    opt = Option("q", float, np.float32(0.5), minimum=np.float64(0.0), maximum=np.int64(1), warm_up=np.float32(1))
    assert [type(x) for x in (opt.default, opt.minimum, opt.maximum, opt.warm_up)] == [float, float, int, float]
    json.dumps([opt.default, opt.minimum, opt.maximum])


def test_a_plugin_that_swallows_the_interrupt_still_stops_the_render(tmp_path):
    """A plug-in's `except BaseException` ate the KeyboardInterrupt of SIGTERM: the render went on, wrote its image
    and exited 0. The stop is remembered and honoured at the next safe point."""
    (tmp_path / "plug").mkdir()
    (tmp_path / "plug" / "p.py").write_text(
        "import time\nfrom pathlib import Path\n\nfrom probvis.visibility.exact import ExactVisibility\n\n\n"
        "class Stubborn(ExactVisibility):\n    name = 'stubborn'\n\n    def prepare(self, *args):\n"
        "        super().prepare(*args)\n        Path(__file__).with_name('started').touch()\n"
        "        for _ in range(15):\n            try:\n                time.sleep(0.2)\n"
        "            except BaseException:\n                pass\n")
    out = tmp_path / "out"
    out.mkdir()
    proc = subprocess.Popen([sys.executable, "-m", "probvis", "render", "quad-shadow", "-D", "res=8", "--spp", "1",
                             "-o", str(out / "o.exr"), "--visibility", f"{tmp_path / 'plug' / 'p.py'}:Stubborn"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    started = tmp_path / "plug" / "started"
    deadline = time.monotonic() + 600
    while not started.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=600)
    assert proc.returncode == 130 and err.strip().splitlines()[-1] == "probvis: interrupted, nothing written", err
    assert not list(out.iterdir())


def test_renders_from_two_threads_load_their_estimators_one_at_a_time(tmp_path):
    """Two threads' first renders with occlusion-map and probvis (which imports it) raced in the imports: a
    'circular import' error in one thread and an ImportError in the other."""
    code = ("import threading, probvis\nerrors = []\n"
            "def run(v):\n    try:\n        probvis.render('quad-shadow', spp=1, shadow_rays=1, threads=1, "
            "defines={'res': 8}, visibility=v)\n    except Exception as exc:\n        errors.append(repr(exc))\n"
            "ts = [threading.Thread(target=run, args=(v,)) for v in ('occlusion-map', 'probvis')]\n"
            "[t.start() for t in ts]\n[t.join() for t in ts]\nprint(errors)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=600)
    assert r.returncode == 0 and r.stdout.strip() == "[]", r.stdout + r.stderr


@pytest.mark.parametrize("change, message", [
    (lambda e: setattr(e.params, "photons", "many"), r"has settings its class refuses: .*photons"),
    (lambda e: setattr(e.params, "photons", 0), r"has settings its class refuses: .*photons"),
    (lambda e: setattr(e, "params", None), r"has no readable settings"),
    (lambda e: delattr(e, "params"), r"has no readable settings"),
])
def test_an_instance_changed_after_it_was_made_is_checked_again(change, message):
    """`render(visibility=instance)` checks the instance's settings as its class checks options."""
    est = probvis.visibility.make_estimator("occlusion-map", photons=1000)
    change(est)
    with pytest.raises(ProbvisError, match=r"visibility: the OcclusionMapVisibility instance " + message):
        probvis.render("quad-shadow", resolution=(8, 8), spp=1, shadow_rays=1, visibility=est)


def test_installed_estimators_that_do_not_load_do_not_stop_other_renders(roulette, tmp_path, monkeypatch, capsys):
    """Entry points whose module fails to import, calls sys.exit or names a module: each is an error only where it is
    named; a render with another estimator loads none of them, and `probvis estimators` lists them as not loading.
    An entry point to a nested class loads it."""
    from probvis.cli import main
    site = tmp_path / "site"
    site.mkdir()
    (site / "brokemod.py").write_text("import no_such_module_xyz\n")
    (site / "exitmod.py").write_text("import sys\nsys.exit(3)\n")
    (site / "goodmod.py").write_text("X = 5\n")
    (site / "spymod.py").write_text(f"open({str(tmp_path / 'imported')!r}, 'w').close()\n")
    (site / "nestmod.py").write_text(example_source() + "\n\nclass Outer:\n    class P(RouletteVisibility):\n"
                                     "        name = 'nested'\n")
    dist = site / "plugs-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: plugs\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[probvis.visibility]\nbroke = brokemod:P\nexiter = exitmod:P\n"
                                           "modep = goodmod\nnum = goodmod:X\nnested = nestmod:Outer.P\nspy = spymod:P\n")
    monkeypatch.syspath_prepend(str(site))
    assert main(["render", "quad-shadow", "-D", "res=8", "--spp", "1", "--shadow-rays", "1", "-o",
                 str(tmp_path / "o.exr"), "-q"]) == 0
    assert not (tmp_path / "imported").exists()  # probvis's own flags load no other estimator
    assert estimator_class("nested").name == "nested"
    for name, message in [("broke", "ModuleNotFoundError"), ("exiter", "SystemExit: 3"),
                          ("modep", "'goodmod' is not a probvis.visibility.VisibilityEstimator subclass"),
                          ("num", "'goodmod:X' is not a probvis.visibility.VisibilityEstimator subclass")]:
        with pytest.raises(ProbvisError, match=f"cannot load installed estimator '{name}'|{re.escape(message)}"):
            estimator_class(name)
    capsys.readouterr()
    assert main(["estimators"]) == 0
    out = capsys.readouterr().out
    assert "exact  —" in out and "nested  —" in out
    assert all(f"{name}  —  cannot be loaded" in out for name in ("broke", "exiter", "modep", "num", "spy"))


@pytest.mark.parametrize("where", ["import", "prepare", "check"])
def test_unprintable_plugin_exceptions_are_named_wherever_they_arise(tmp_path, capsys, where):
    """An exception whose __str__ raises (or exits) was a traceback when the plug-in's import or an option's check
    raised it, and ended the command with exit 0 and no image when its __str__ called sys.exit."""
    from probvis.cli import main

    body = {"import": "raise BadExit()\n",
            "prepare": "class P(Exact):\n    name = 'p'\n    summary = 's'\n"
                       "    def prepare(self, *a):\n        raise BadExit()\n",
            "check": "class P(Exact):\n    name = 'p'\n    summary = 's'\n"
                     "    options = (Option('k', int, 3, 'k', check=lambda v: Bad()),)\n"}[where]
    (tmp_path / "p.py").write_text(
        "import sys\nfrom probvis.visibility import Option\nfrom probvis.visibility.exact import ExactVisibility as Exact\n"
        "class Bad(Exception):\n    def __str__(self):\n        raise RuntimeError('str fails')\n"
        "class BadExit(Exception):\n    def __str__(self):\n        sys.exit(0)\n" + body)
    code = main(["render", "quad-shadow", "-D", "res=8", "--spp", "1", "--visibility", f"{tmp_path / 'p.py'}:P",
                 "-o", str(tmp_path / "o.exr")])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("probvis: error: ") and err.count("\n") == 1, err
    said = "its check returned Bad() on 3, not an error message" if where == "check" else "its str() failed"
    assert said in err and not (tmp_path / "o.exr").exists()


@pytest.mark.parametrize("field", ["name", "summary", "option name", "phase help", "AOV name"])
def test_declarations_that_cannot_be_printed_are_named(field):
    """A declared name or text of a str subclass whose __format__/__repr__ fails (or exits) was a traceback, or
    exit 0 with nothing written; declarations are exact strings."""
    class Bad(str):
        def __repr__(self):
            raise SystemExit(0)

        def __format__(self, spec):
            raise RuntimeError("format fails")

    attrs = {"name": "p", "summary": "s"}
    if field in ("name", "summary"):
        attrs[field] = Bad("p")
    elif field == "option name":
        attrs["options"] = (probvis.visibility.Option(Bad("k"), int, 3, "k"),)
    elif field == "phase help":
        attrs["phases"] = (probvis.visibility.Phase("ph", "batch", Bad("h")),)
    else:
        attrs["aovs"] = (probvis.visibility.Aov(Bad("x"), "segment", "x"),)
    cls = type("Unprintable", (_Exact,), attrs)
    with pytest.raises(ProbvisError, match=r"(name|names|help|summary).* got <Bad: its repr\(\) failed>"):
        probvis.render("quad-shadow", spp=1, visibility=cls)


class _RefusesTheWarmUp(probvis.visibility.estimator_class("exact")):
    """A plug-in whose own check refuses the warm-up's scene (as one that needs a named mesh would)."""

    name = "picky"
    summary = "renders the Cornell box only"

    def prepare(self, scene, bvh, emitters, settings, integrator):
        if scene.name != "cornell-box":
            raise ProbvisError(f"needs the Cornell box, got '{scene.name}'")
        super().prepare(scene, bvh, emitters, settings, integrator)


def test_a_plugin_that_refuses_the_warm_up_s_scene_renders_its_own(monkeypatch):
    """The warm-up renders a scene of its own first; a plug-in that refuses it is not warmed up (its render
    compiles what it runs), and still reports what it refuses in the render itself."""
    from probvis import warm_up

    monkeypatch.setattr(warm_up, "_warmed", set())
    monkeypatch.setattr(warm_up, "_failed", set())
    image = probvis.render("cornell-box", resolution=(4, 4), spp=1, visibility=_RefusesTheWarmUp).image
    assert image.shape == (4, 4, 3)
    assert warm_up._failed and not warm_up._warmed  # not warm: its kernels count in the estimate
    with pytest.raises(ProbvisError, match="needs the Cornell box, got 'quad-shadow'"):
        probvis.render("quad-shadow", resolution=(4, 4), spp=1, visibility=_RefusesTheWarmUp)


class _FakeFused(probvis.visibility.VisibilityEstimator):
    """Says the fused kernel renders it, whose evaluate is not exact visibility."""

    name = "fake-fused"
    summary = "a quarter of every segment"

    def render_path(self):
        return probvis.visibility.RenderPath.FUSED_EXACT

    def evaluate(self, query):
        n = len(query.tmax)
        return probvis.visibility.VisibilityResult(np.full(n, 0.25), np.zeros(n, np.int64), np.zeros(n, np.int64))


def test_a_plugin_on_the_fused_path_must_be_exact_visibility():
    """FUSED_EXACT renders exact visibility instead of `evaluate`: a plug-in whose evaluate is not exact got
    exact visibility's image under its own name (exit 0); its first batch's segments are compared."""
    with pytest.raises(ProbvisError, match=r"render_path\(\) returned FUSED_EXACT, which renders exact visibility "
                                           r"instead of evaluate, but evaluate returned 0.25 where it is (1|0): return "
                                           r"STAGED"):
        probvis.render("quad-shadow", resolution=(8, 8), spp=1, visibility=_FakeFused)
    exact = type("Exactly", (_Exact,), {"render_path": lambda self: probvis.visibility.RenderPath.FUSED_EXACT})
    assert probvis.render("quad-shadow", resolution=(8, 8), spp=1, visibility=exact).image.mean() > 0


def test_a_percent_sign_in_an_option_s_help_reaches_the_help(capsys):
    """`--help` with a plug-in whose option help says '50% by default' was argparse's formatting traceback."""
    cls = type("Pct", (_Exact,), {"options": (probvis.visibility.Option("share", float, 0.5, "a share, 50% by "
                                                                                       "default"),)})
    from probvis import cli

    with pytest.raises(SystemExit):
        cli._parser(cls).parse_args(["render", "x", "--help"])
    assert "a share, 50% by default" in capsys.readouterr().out


def _slow_prepare(self, *args):
    """A "batch" phase timed in prepare, as long as no 8x8 render's batches take (not a sleep: on a busy
    machine the render could outlast it)."""
    _Exact.prepare(self, *args)
    with self.timed("late"):
        pass
    self.seconds["late"] += 1000.0


@pytest.mark.parametrize("declared, message", [
    ({"phases": (probvis.visibility.Phase("late", "batch"),), "prepare": _slow_prepare},
     r"its batch phases \(late\) took 1e\+03 s, more than the render \(the batches\) took"),
    ({"stats": lambda self: {**_Exact.stats(self), "tests": {"proxy": {"node": 10 ** 9, "triangle": 0}}}},
     r"\['tests'\]\['proxy'\]\['node'\] is 1,000,000,000, more than the [\d,]+ node tests its evaluate returned"),
])
def test_a_plugin_s_accounts_must_fit_the_render_s(declared, message):
    """A phase declared "batch" but timed in prepare made a study's render seconds negative, and proxy tests
    beyond the shadow rays' made its scene tests negative (exit 0 both)."""
    cls = type("Accounts", (_Exact,), declared)
    with pytest.raises(ProbvisError, match=message):
        probvis.render("quad-shadow", resolution=(8, 8), spp=1, visibility=cls)
