"""Experiment files: the shipped ones parse; every mistake is one clear error naming what is wrong."""
import os
import re
from pathlib import Path

import numpy as np
import pytest

from probvis.errors import ProbvisError
from probvis.experiments import load_experiment, parse_experiment, quick_experiment

MINIMAL = {"scenes": [{"name": "q", "source": "quad-shadow"}], "methods": [{"name": "e", "visibility": "exact"}]}


def doc(**changes):
    d = {k: [dict(x) for x in v] for k, v in MINIMAL.items()}
    d.update(changes)
    return d


def test_quick_preset_covers_every_estimator():
    exp = quick_experiment()
    assert exp.baseline == "om-list"
    assert {m.options.get("estimator") for m in exp.methods if m.visibility == "probvis"} == {
        "standard", "shifted", "power", "adaptive"}
    assert exp.shadow_rays == (1, 4, 16, 64, 256)


def test_proxies_experiment_parses(shared):

    folder = Path(__file__).resolve().parents[2] / "experiments"
    exp, sixteen = load_experiment(folder / "proxies.toml"), load_experiment(folder / "proxies-16spp.toml")
    assert exp.seconds == "render" and exp.baseline == "exact"
    assert {m.visibility for m in exp.methods} == {"exact", "proxy", "occlusion-map"}
    assert (exp.spp, exp.shadow_rays, sixteen.spp, sixteen.shadow_rays) == (4, (16, 64), 16, (16,))
    assert sixteen.methods == exp.methods and sixteen.scenes == exp.scenes


def test_paper_experiment_parses(shared):

    exp = load_experiment(Path(__file__).resolve().parents[2] / "experiments" / "paper.toml")
    assert [s.name for s in exp.scenes] == ["city", "leaves", "cornell-bunny"]
    assert all(s.reference and s.reference.endswith("-128.exr") for s in exp.scenes)


def test_defaults_and_baseline():
    assert parse_experiment(doc()).seconds == "total" and parse_experiment(doc(seconds="render")).seconds == "render"
    exp = parse_experiment(doc(shadow_rays=[16, 1]))
    assert exp.shadow_rays == (1, 16) and exp.baseline == "e" and exp.seeds == (0,)
    assert exp.reference.visibility == "exact"


@pytest.mark.parametrize("change, message", [
    ({"colour": 1}, "unknown key 'colour'"),
    ({"scenes": [{"name": "q", "source": "quad-shadow", "defnes": {}}]}, "scenes[0]: unknown key 'defnes'"),
    ({"scenes": [{"name": "q", "source": "no-such-scene"}]}, "neither a built-in scene"),
    ({"scenes": [{"name": "q"}]}, "scenes[0]: missing key 'source'"),
    ({"methods": [{"name": "m", "visibility": "magic"}]}, "unknown visibility 'magic'"),
    ({"methods": [{"name": "m", "visibility": "probvis", "options": {"estimator": "nope"}}]}, "method 'm'"),
    ({"methods": [{"name": "m", "visibility": "probvis", "options": {"colour": 3}}]}, "has no option 'colour'"),
    ({"methods": [{"name": "m", "visibility": "exact"}, {"name": "m", "visibility": "exact"}]},
     "repeated method name 'm'"),
    ({"methods": [{"name": "a", "visibility": "exact", "baseline": True},
                  {"name": "b", "visibility": "exact", "baseline": True}]}, "only one method can be the baseline"),
    ({"shadow_rays": [1, 0]}, "shadow_rays[1]: expected a whole number >= 1"),
    ({"shadow_rays": []}, "shadow_rays: expected a non-empty list"),
    ({"resolution": [16, 16, 16]}, "resolution: expected [width, height]"),
    ({"reference": {"sp": 3}}, "reference: unknown key 'sp'"),
    ({"target_relmse": -1}, "target_relmse: expected a positive number"),
    ({"target_relmse": float("inf")}, "target_relmse: expected a positive number"),
    ({"spp": 10 ** 30}, "spp: expected a whole number <= 1048576"),
    ({"seeds": [2 ** 63]}, "seeds[0]: expected a whole number <= 9223372036854775807"),
    ({"resolution": [100000, 8]}, "resolution[0]: expected a whole number <= 32768"),
    ({"table_shadow_rays": 8}, "table_shadow_rays: 8 is not one of shadow_rays"),
    ({"methods": []}, "at least one [[methods]]"),
    ({"seconds": "wall"}, "seconds: expected one of total, render, got 'wall'"),
    ({"timing_seconds": 0}, "timing_seconds: expected a number of seconds > 0, got 0"),
    ({"timing_seconds": float("nan")}, "timing_seconds: expected a number of seconds > 0, got nan"),
    ({"timing_seconds": "2"}, "timing_seconds: expected a number of seconds > 0, got '2'"),
    ({"description": 5}, "description: expected a string, got 5"),
])
def test_mistakes_are_named(change, message):
    with pytest.raises(ProbvisError) as info:
        parse_experiment(doc(**change))
    assert message in str(info.value)
    assert "\n" not in str(info.value)


def test_files(tmp_path):
    with pytest.raises(ProbvisError, match="experiment file not found"):
        load_experiment(tmp_path / "missing.toml")
    with pytest.raises(ProbvisError, match="path must be an experiment file's path, got int"):
        load_experiment(5)
    with pytest.raises(ProbvisError, match="is a folder, not an experiment file"):
        load_experiment(tmp_path)


def test_a_device_or_pipe_is_no_experiment_file_nor_scene_source(tmp_path):
    """/dev/null or a FIFO exists: "not found" misled."""
    os.mkfifo(tmp_path / "pipe")
    for path in ("/dev/null", tmp_path / "pipe"):
        with pytest.raises(ProbvisError, match=re.escape(f"{path} is not a regular file (a pipe, socket or device), "
                                                         "not an experiment file")):
            load_experiment(path)
    with pytest.raises(ProbvisError, match=r"scenes\[0\]\.source: .*pipe is not a regular file"):
        parse_experiment(doc(scenes=[{"name": "q", "source": "pipe"}]), base=tmp_path)
    bad = tmp_path / "bad.toml"
    bad.write_text("name = 'x'\n[[scenes]\n")
    with pytest.raises(ProbvisError, match=r"bad.toml: malformed TOML: .*line 2"):
        load_experiment(bad)
    bad.write_text("name = 'x'\n", encoding="utf-16")
    with pytest.raises(ProbvisError, match=r"bad.toml: not UTF-8 text"):
        load_experiment(bad)
    rel = tmp_path / "rel.toml"
    rel.write_text("[[scenes]]\nname = 'a'\nsource = 'scene.xml'\n[[methods]]\nname = 'e'\nvisibility = 'exact'\n")
    with pytest.raises(ProbvisError, match=r"looked for .*scene.xml"):
        load_experiment(rel)


def test_a_tilde_in_a_study_s_paths_is_the_home(tmp_path, monkeypatch):
    """`source`, `reference` and a plug-in file read ~ as the shell does (PROBVIS_CACHE_DIR did already)."""
    monkeypatch.setenv("HOME", str(tmp_path))
    (tmp_path / "s.xml").write_text("<scene version='3.0.0'/>")
    (tmp_path / "r.exr").write_bytes(b"")
    (tmp_path / "e.py").write_text("from probvis.visibility import estimator_class\n\n\n"
                                   "class E(estimator_class('exact')):\n    name = 'tilde'\n")
    exp = parse_experiment({"scenes": [{"name": "a", "source": "~/s.xml", "reference": "~/r.exr"}],
                            "methods": [{"name": "e", "visibility": "~/e.py:E"}]}, base=tmp_path / "elsewhere")
    assert exp.scenes[0].source == str(tmp_path / "s.xml") and exp.scenes[0].reference == str(tmp_path / "r.exr")
    assert exp.methods[0].visibility == f"{tmp_path / 'e.py'}:E"


def test_command_line_mistakes_exit_2_with_one_line(tmp_path, capsys):
    from probvis.cli import main

    assert main(["experiment"]) == 2
    assert main(["experiment", str(tmp_path / "missing.toml")]) == 2
    assert main(["experiment", "--quick", "--scheduler", "tcp://127.0.0.1:1", "--workers", "2"]) == 2
    assert main(["experiment", "--quick", "--workers", "100000"]) == 2
    assert main(["experiment", "--quick", "--scheduler", "not a url"]) == 2
    assert main(["experiment", "--quick", "--scheduler="]) == 2  # an unset variable: not a local cluster instead
    err = capsys.readouterr().err.splitlines()
    assert err == ["probvis: error: give an experiment file (e.g. experiments/paper.toml) or --quick",
                   f"probvis: error: experiment file not found: {tmp_path / 'missing.toml'}",
                   "probvis: error: --workers applies to the embedded LocalCluster, not to --scheduler",
                   f"probvis: error: argument --workers: must be at most {4 * (os.cpu_count() or 1)}, got 100000",
                   "probvis: error: --scheduler 'not a url' is not a scheduler address (tcp://host:port)",
                   "probvis: error: --scheduler needs a Dask scheduler's address (tcp://host:port); it is empty "
                   "(leave the option out for a local cluster)"]


@pytest.mark.parametrize("change, message", [
    ({"methods": [{"name": "e", "visibility": "exact", "baseline": "yes"}]}, "methods[0].baseline: expected true"),
    ({"reference": {"visibility": "magic"}}, "reference.visibility: unknown visibility 'magic'"),
    ({"name": "../../escape"}, "name: must be a plain name"),
    ({"name": "a" * 300}, "name: is 300 characters long, more than a name of files and folders may be (100)"),
    ({"scenes": [{"name": "q", "source": "quad-shadow", "defines": 3}]}, "scenes[0].defines: expected a table"),
])
def test_more_mistakes_are_named(change, message):
    with pytest.raises(ProbvisError, match=re.escape(message)):
        parse_experiment(doc(**change))


def test_table_column_defaults_to_16_rays_or_the_most():
    assert parse_experiment(doc(shadow_rays=[1, 16, 64])).table_shadow_rays == 16
    assert parse_experiment(doc(shadow_rays=[1, 4])).table_shadow_rays == 4


def test_a_reference_that_is_not_an_exr_is_refused_before_any_render(tmp_path):
    (tmp_path / "r.png").write_bytes(b"\x89PNG")
    change = {"scenes": [{"name": "q", "source": "quad-shadow", "reference": "r.png"}]}
    with pytest.raises(ProbvisError, match=re.escape("scenes[0].reference: r.png is not an EXR or PFM image")):
        parse_experiment(doc(**change), tmp_path)


def test_a_byte_order_mark_is_allowed(tmp_path):
    """A UTF-8 file saved with a byte-order mark (Windows editors) is UTF-8: tomllib alone called it an invalid
    statement at line 1."""
    text = ("name = 'bom'\nresolution = [8, 8]\n[[scenes]]\nname = 'q'\nsource = 'quad-shadow'\n"
            "[[methods]]\nname = 'm'\nvisibility = 'exact'\n")
    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbf" + text.encode())
    assert load_experiment(path).name == "bom"


def test_a_plugin_method_whose_init_raises_is_named(tmp_path):
    """Only ProbvisError was caught around the method's construction: a plug-in's own bug was a traceback."""
    (tmp_path / "p.py").write_text("import probvis\n\n\nclass X(probvis.visibility.VisibilityEstimator):\n"
                                   "    name = 'x'\n\n    def __init__(self, **options):\n"
                                   "        raise ValueError('boom')\n\n    def evaluate(self, query):\n"
                                   "        pass\n")
    change = {"methods": [{"name": "e", "visibility": str(tmp_path / "p.py") + ":X"}]}
    with pytest.raises(ProbvisError, match=r"method 'e': visibility '.*p.py:X' \(.*X\) raised ValueError in "
                                           r"__init__: boom"):
        parse_experiment(doc(**change))


def test_the_experiment_api_names_wrong_argument_types(tmp_path):
    from probvis.experiments import experiment, quick_experiment

    for kwargs, message in ((dict(workers="2"), "workers must be a whole number from 1, got '2'"),
                            (dict(cache=5), "cache must be a folder"), (dict(scheduler=5), "scheduler must be")):
        with pytest.raises(ProbvisError, match=message):
            experiment(quick_experiment(), tmp_path / "rep", **kwargs)
    with pytest.raises(ProbvisError, match="base must be the folder relative paths start from"):
        parse_experiment(doc(), base=5)


def test_the_experiment_building_blocks_refuse_what_is_not_their_record(tmp_path):
    from probvis.experiments import load_experiment, measure, quick_experiment, run_experiment, write_report

    exp = quick_experiment()
    for call, message in ((lambda: quick_experiment(1), r"quick_experiment\(\): too many positional arguments"),
                          (lambda: load_experiment(), r"load_experiment\(\): missing a required argument: 'path'"),
                          (lambda: run_experiment(1, tmp_path), "exp must be an Experiment .*got int"),
                          (lambda: run_experiment(exp, 5), "cache_dir must be a folder"),
                          (lambda: run_experiment(exp, tmp_path, workers=0), "workers must be a whole number from 1"),
                          (lambda: measure(exp, {}), "run must be the RunSummary run_experiment returns, got dict"),
                          (lambda: write_report("x.toml", 1, 2, tmp_path), "exp must be an Experiment")):
        with pytest.raises(ProbvisError, match=message):
            call()
    assert not (tmp_path / "cache").exists() and not any(tmp_path.iterdir())


def test_an_experiment_built_in_python_may_use_tuples_and_numpy():
    """Tuples, NumPy arrays and NumPy scalars (and 0-d arrays) read as TOML's lists and numbers (they were
    refused, or a key of the wrong type failed deep inside the runner; a 0-d array was a TypeError)."""
    plain = parse_experiment(doc(spp=2, resolution=[8, 8], shadow_rays=[1, 4],
                                 methods=[{"name": "p", "visibility": "probvis",
                                           "options": {"probabilities": [0.2, 0.4, 0.4]}}]))
    numpy = parse_experiment(doc(spp=np.array(2), resolution=np.array([8, 8]), shadow_rays=(1, np.uint8(4)),
                                 scenes=({"name": "q", "source": Path("quad-shadow")},),
                                 methods=[{"name": "p", "visibility": "probvis",
                                           "options": {"probabilities": np.array([0.2, 0.4, 0.4])}}]))
    assert numpy == plain
    assert parse_experiment(doc(target_relmse=np.longdouble(0.5))).target_relmse == 0.5  # was no number
    with pytest.raises(ProbvisError, match=r"scenes\[0\].defines: parameter names must be non-empty strings, got 1"):
        parse_experiment(doc(scenes=[dict(MINIMAL["scenes"][0], defines={1: 2})]))
    with pytest.raises(ProbvisError, match=r"scenes\[0\].defines.spp: the study sets every cell's spp \(spp at the "
                                           r"top of the file"):  # it was silently overridden
        parse_experiment(doc(scenes=[dict(MINIMAL["scenes"][0], defines={"spp": 100})]))
    for value in ({8}, None, object()):  # were rendered as their str(): '{8}', 'None', an address in the cache key
        with pytest.raises(ProbvisError, match=r"scenes\[0\].defines.res: expected a number, string or boolean"):
            parse_experiment(doc(scenes=[dict(MINIMAL["scenes"][0], defines={"res": value})]))


def test_the_experiment_api_takes_numpy_workers_and_refuses_empty_folders(tmp_path):
    from probvis.experiments import experiment, quick_experiment

    for kwargs, message in ((dict(cache=""), "cache must name a folder, got an empty name"),
                            (dict(workers=np.int64(0)), "workers")):
        with pytest.raises(ProbvisError, match=message):
            experiment(quick_experiment(), tmp_path / "rep", **kwargs)
    with pytest.raises(ProbvisError, match="out must name a folder"):
        experiment(quick_experiment(), "")
    with pytest.raises(ProbvisError, match=r"exp must be an Experiment \(parse_experiment builds one from a dict\)"):
        experiment({"scenes": []}, tmp_path / "rep")


def test_studies_beyond_what_a_render_or_a_report_takes_are_refused():
    """A million cells were accepted (SIGTERM then took 327 s); so were 2^36 shadow rays per pixel, which made
    one batch that no interrupt could stop."""
    with pytest.raises(ProbvisError, match="experiment: 5,242,880 cells .* is more than a study runs"):
        parse_experiment(doc(seeds=list(range(1 << 20))))
    with pytest.raises(ProbvisError, match="spp x shadow_rays: 1048576 x 65536 is more than the 67,108,864"):
        parse_experiment(doc(spp=1 << 20, shadow_rays=[65536]))
    with pytest.raises(ProbvisError, match="reference.spp x reference.shadow_rays: 65536 x 65536"):
        parse_experiment(doc(reference={"spp": 65536, "shadow_rays": 65536}))


@pytest.mark.parametrize("text, message", [
    ("spp = " + "9" * 5000 + "\n", "unreadable TOML: Exceeds the limit (4300 digits)"),
    ("x = " + "[" * 5000 + "]" * 5000 + "\n", "unreadable TOML: arrays or tables nested too deep"),
])
def test_toml_beyond_python_s_limits_is_one_error(tmp_path, text, message):
    """tomllib raises ValueError or RecursionError there, not TOMLDecodeError: they were tracebacks."""
    (tmp_path / "e.toml").write_text(text)
    with pytest.raises(ProbvisError, match=re.escape(message)):
        load_experiment(tmp_path / "e.toml")


def test_an_experiment_that_contains_itself_is_named():
    cyclic = doc()
    cyclic["seeds"] = [0]
    cyclic["seeds"].append(cyclic["seeds"])
    with pytest.raises(ProbvisError, match="nests lists or dicts more than 16 deep"):
        parse_experiment(cyclic)


def test_a_plugin_reference_estimator_is_found_beside_the_experiment_file(tmp_path, monkeypatch):
    """The methods' `file.py:Class` were resolved against the experiment's folder, the reference's against the
    current folder."""
    (tmp_path / "plug.py").write_text("from probvis.visibility.exact import ExactVisibility\n\n\n"
                                      "class Mine(ExactVisibility):\n    name = 'mine'\n")
    (tmp_path / "e.toml").write_text('[reference]\nvisibility = "plug.py:Mine"\n[[scenes]]\nname = "q"\n'
                                     'source = "quad-shadow"\n[[methods]]\nname = "e"\nvisibility = "exact"\n')
    monkeypatch.chdir("/")
    assert load_experiment(tmp_path / "e.toml").reference.visibility == f"{tmp_path / 'plug.py'}:Mine"


@pytest.mark.parametrize("name", ["a\tb", "x\u202ey", "line\nbreak"])
def test_names_with_control_characters_are_refused(name):
    """A tab or a right-to-left override in a method's name reached the report's plots (matplotlib warned of the
    missing glyph) and its text."""
    with pytest.raises(ProbvisError, match=r"methods\[0\].name: control characters"):
        parse_experiment(doc(methods=[{"name": name, "visibility": "exact"}]))


def test_option_names_must_be_strings():
    """A NaN key through the API was blamed on the built-in estimator's __init__."""
    with pytest.raises(ProbvisError, match=r"methods\[0\].options: option names must be strings"):
        parse_experiment(doc(methods=[{"name": "e", "visibility": "occlusion-map", "options": {float("nan"): 3}}]))


def test_an_experiment_changed_in_python_is_checked_again(tmp_path):
    """`experiment()` parses an `Experiment` it is given again, as a file's: a field replaced with a wrong type
    or value (the CLI replaces `seeds`) is refused before any render, naming the field."""
    import dataclasses

    from probvis.experiments import experiment

    exp = parse_experiment(doc(spp=1, resolution=[8, 8], shadow_rays=[1]))
    for change, message in ((dict(methods=("exact",)), "methods: expected a tuple of MethodSpecs"),
                            (dict(table_shadow_rays=99), "table_shadow_rays: 99 is not one of shadow_rays"),
                            (dict(baseline="nope"), "baseline: 'nope' is not one of the methods (e)"),
                            (dict(spp=0), "spp"), (dict(seeds=(-1,)), "seeds")):
        with pytest.raises(ProbvisError, match=re.escape(message)):
            experiment(dataclasses.replace(exp, **change), tmp_path / "rep")
    for kwargs, message in ((dict(progress="no"), "progress must be True or False, got 'no'"),
                            (dict(command=123), "command must be the command line shown in the report"),
                            (dict(log=5), "log must be a function taking a line")):
        with pytest.raises(ProbvisError, match=re.escape(message)):
            experiment(exp, tmp_path / "rep", **kwargs)
    assert not (tmp_path / "rep").exists()


@pytest.mark.parametrize("setup, message", [
    (lambda rep: (rep / "index.html").mkdir(parents=True), "'{rep}/index.html' is a folder, where the report writes"),
    (lambda rep: (rep / "data" / "q.js").mkdir(parents=True), "'{rep}/data/q.js' is a folder"),
    (lambda rep: (rep.mkdir(), (rep / "images").write_text("x")), "'{rep}/images' is a file, where the report keeps"),
])
def test_a_report_that_could_not_be_written_whole_is_refused_before_any_render(tmp_path, setup, message):
    from probvis.experiments import experiment

    rep = tmp_path / "rep"
    setup(rep)
    before = sorted(p.relative_to(rep) for p in rep.rglob("*"))
    with pytest.raises(ProbvisError, match=re.escape(message.format(rep=rep))):
        experiment(parse_experiment(doc(spp=1, resolution=[8, 8], shadow_rays=[1])), rep)
    assert sorted(p.relative_to(rep) for p in rep.rglob("*")) == before  # no cache, no renders


def test_the_libraries_environment_is_taken_in_stride(tmp_path, monkeypatch):
    """A bogus MPLBACKEND (validated by matplotlib as it loads) does not stop the report's plots; a Dask
    configuration file that is not YAML is one line naming DASK_CONFIG; '~' in PROBVIS_CACHE_DIR is the home."""
    import subprocess
    import sys

    env = dict(os.environ, MPLBACKEND="bogus")
    code = "from probvis.experiments.report import _pyplot; print(_pyplot().get_backend())"
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.strip().lower() == "agg" and not r.stderr, r.stderr
    (tmp_path / "bad.yaml").write_text("distributed: [unclosed\n  :: x\n")
    code = "from probvis.experiments.runner import _open_client; _open_client(1, None)"
    r = subprocess.run([sys.executable, "-c", code], env=dict(os.environ, DASK_CONFIG=str(tmp_path)),
                       capture_output=True, text=True)
    assert f"ProbvisError: cannot load Dask (DASK_CONFIG={tmp_path}): ValueError: A dask config file" in r.stderr
    from probvis.disk_cache import cache_dir

    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.setenv("PROBVIS_CACHE_DIR", "~/pc")
    assert cache_dir("plans") == tmp_path / "pc" / "plans"


def test_a_report_whose_writing_fails_leaves_no_file_of_it(tmp_path, monkeypatch):
    """A write that fails half-way (a full disk, ulimit -f) left the images, plots and data of a report without
    its index.html: the report's files are renamed together at the end, all or none."""
    from probvis.experiments import experiment
    from probvis.experiments.report import Report

    def full(self):
        raise OSError(28, "No space left on device", str(self.folder / "results.md"))

    monkeypatch.setattr(Report, "_markdown", full)
    rep = tmp_path / "rep"
    with pytest.raises(ProbvisError, match="No space left on device"):
        experiment(parse_experiment(doc(spp=1, resolution=[8, 8], shadow_rays=[1])), rep, progress=False)
    assert not [p for p in rep.rglob("*") if p.is_file() and "cache" not in p.relative_to(rep).parts]


def test_a_reference_that_would_share_a_cell_s_samples_or_a_target_beyond_reach_is_refused(tmp_path):
    """A rendered reference with a cell's seed made that cell's relMSE 0 (a NaN in the report's JSON, a
    traceback after every render); a target relMSE of 1e300 overflowed in the time-to-target fit."""
    with pytest.raises(ProbvisError, match=r"reference.seed: 0 \(the rendered reference's seed\) is one of the "
                                           r"cells' seeds \(seeds, or --seeds\).*choose other seeds, or set "):
        parse_experiment(doc(seeds=[0], reference={"seed": 0}))
    from probvis.io import write_exr

    write_exr(tmp_path / "r.exr", np.full((8, 8, 3), 0.5, np.float32))  # a reference file: no rendered one
    parse_experiment(doc(seeds=[0], reference={"seed": 0},
                         scenes=[{"name": "q", "source": "quad-shadow", "reference": str(tmp_path / "r.exr")}]))
    with pytest.raises(ProbvisError, match="target_relmse: expected a positive number up to 1e"):
        parse_experiment(doc(target_relmse=1e300))


def test_the_bias_ratio_of_an_image_smaller_than_a_block():
    """A 4x4 study image (two seeds) was 'cannot reshape array of size 0' after every render."""
    from probvis.experiments.metrics import block_bias_ratio

    rng = np.random.default_rng(0)
    ref = np.full((4, 4, 3), 0.5)
    a, b = ref + rng.normal(0, 0.01, ref.shape), ref + rng.normal(0, 0.01, ref.shape)
    assert np.isfinite(block_bias_ratio(a, b, ref))


@pytest.mark.parametrize("key", ["source", "reference"])
def test_a_scene_or_reference_that_loops_is_named(tmp_path, key):
    """A symbolic link loop as a scene's source or reference was a RuntimeError traceback from Path.resolve."""
    (tmp_path / "loop.xml").symlink_to("loop.xml")
    scene = {"name": "q", "source": "quad-shadow", key: "loop.xml"}
    with pytest.raises(ProbvisError, match=rf"scenes\[0\]\.{key}: .*loop.xml: a symbolic link that loops"):
        parse_experiment(doc(scenes=[scene]), tmp_path)


def test_a_scene_define_of_res_beside_the_study_s_resolution_is_refused():
    """`resolution = [8, 8]` with a scene's `defines = { res = 16 }` rendered 8x8: the define did nothing."""
    with pytest.raises(ProbvisError, match=r"scenes\[0\].defines.res: the study sets every cell's film size"):
        parse_experiment(doc(resolution=[8, 8], scenes=[dict(MINIMAL["scenes"][0], defines={"res": 16})]))
    assert parse_experiment(doc(scenes=[dict(MINIMAL["scenes"][0], defines={"res": 16})])).scenes[0].defines


def test_a_scene_define_the_scene_does_not_declare_is_refused(tmp_path):
    """A misspelt define of a scene file (`rez` for `res`) was a warning worded for -D, and the study rendered
    every cell without it (sweep 42); a built-in scene refused it already."""
    from probvis.experiments.runner import load_scenes
    from tests.conftest import sensor, write_scene

    path = write_scene(tmp_path / "s.xml", sensor(w="$res", h="$res") + "<shape type='rectangle'/><emitter "
                       "type='point'><point name='position' x='0' y='0' z='1'/></emitter>",
                       '<default name="res" value="8"/>')
    exp = parse_experiment(doc(scenes=[{"name": "s", "source": str(path), "defines": {"rez": 16}}]))
    with pytest.raises(ProbvisError, match=r"scenes\[0\].defines: scene 's' declares no parameter rez \(its "
                                           r"parameters: res\): correct or remove it"):
        load_scenes(exp)
    exp = parse_experiment(doc(scenes=[{"name": "s", "source": str(path), "defines": {"res": 16}}]))
    assert load_scenes(exp)["s"].camera.width == 16
