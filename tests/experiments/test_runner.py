"""The runner on a tiny study: cached renders, resume, identical numbers on 1 or 2 workers, clear failures."""
import errno
import os
import json
import re
import socket
import threading

import numpy as np
import pytest

import probvis
from probvis.errors import ProbvisError
from probvis.experiments import experiment, parse_experiment
from probvis.experiments import report as report_module
from probvis.experiments import runner
from probvis.experiments.runner import Cache, load_scenes, plan

TINY = {
    "name": "tiny", "spp": 2, "shadow_rays": [1, 4], "seeds": [3], "resolution": [12, 12],
    "reference": {"spp": 4, "shadow_rays": 16},
    "scenes": [{"name": "quad", "source": "quad-shadow"}],
    "methods": [{"name": "exact", "visibility": "exact"},
                {"name": "om-list", "visibility": "occlusion-map", "options": {"penumbra": "list", "photons": 4000},
                 "baseline": True},
                {"name": "shifted", "visibility": "probvis", "options": {"estimator": "shifted", "photons": 4000}}],
}


ASSET_PNG = bytes.fromhex("89504e470d0a1a0a0000000d4948445200000001000000010802000000907753de0000000c4944415478"
                          "9c63f8cfc0000003010100c9fe92ef0000000049454e44ae426082")  # one red pixel


def numbers(results):
    """Everything but times."""
    keep = ("scene", "method", "shadow_rays", "seed", "shadow_rays_traced", "triangle_tests", "node_tests",
            "relmse", "rmse", "negative_pixel_share", "tests_change")
    return [{k: r[k] for k in keep} for r in results.cells]


@pytest.fixture(scope="module")
def scheduler():
    """An in-process Dask cluster for the tests whose subject is not the local cluster (a cache, a report): a study
    on it renders what one on its own LocalCluster does (`test_an_existing_scheduler_gives_the_same_numbers`)
    without starting a worker process, which loads the libraries and kernels anew, for every study."""
    from dask.distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        yield cluster.scheduler_address


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny")
    results, index, run = experiment(parse_experiment(TINY), out, progress=False, log=lambda m: None)
    return out, results, index, run


def test_first_run_renders_everything_and_writes_the_report(tiny_run):
    out, results, index, run = tiny_run
    assert run.computed == 6 + 1 and run.cells_cached == 0
    assert index == out / "index.html"
    for name in ("results.csv", "results.json", "results.md", "viewer.js", "report.css", "data/quad.js",
                 "images/quad/reference.png", "images/quad/shifted-4.png", "plots/quad-convergence.png",
                 "plots/quad-cost.png", "plots/quad-tests-1.png"):
        assert (out / name).stat().st_size > 0, name
    doc = json.loads((out / "results.json").read_text())
    assert len(doc["cells"]) == 6 and doc["experiment"]["baseline"] == "om-list"
    base = [r for r in results.cells if r["method"] == "om-list"]
    assert all(r["tests_change"] == 0 for r in base)
    shifted = {r["shadow_rays"]: r for r in results.cells if r["method"] == "shifted"}
    assert shifted[4]["relmse"] < shifted[1]["relmse"]  # more shadow rays, less error
    assert (out / "results.csv").read_text().count("\n") == 7


def test_results_rank_the_methods_by_efficiency(tiny_run):
    """results.md ranks the methods by the geometric mean of their efficiency against the baseline over every
    cell (the baseline's is 1), then gives each scene's seconds to a target error in the same order."""
    out, results, _, _ = tiny_run
    ranking = (out / "results.md").read_text().split("## Ranking", 1)[1]
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in ranking.splitlines()
            if line[:4] in ("| 1 ", "| 2 ", "| 3 ")]
    assert [r[0] for r in rows] == ["1", "2", "3"]
    gmean = {r[1]: float(r[2]) for r in rows}
    assert gmean["om-list"] == 1.0 and set(gmean) == {"exact", "om-list", "shifted"}
    assert [float(r[2]) for r in rows] == sorted((float(r[2]) for r in rows), reverse=True)
    for name in ("exact", "shifted"):
        eff = [r["efficiency_vs_baseline"] for r in results.summary if r["method"] == name]
        assert abs(gmean[name] - float(np.exp(np.mean(np.log(eff))))) < 0.05 * gmean[name]
    assert "Seconds to reach each scene's target relMSE" in ranking


def test_resume_recomputes_nothing_then_only_what_is_missing(tiny_run, tmp_path, scheduler):
    out, results, _, run = tiny_run
    again, _, run2 = experiment(parse_experiment(TINY), out, scheduler=scheduler, progress=False,
                                log=lambda m: None)
    assert run2.computed == 0 and run2.cells_cached == 6
    assert numbers(again) == numbers(results)
    victim = next(t for t in run.tasks if t.method.name == "shifted" and t.shadow_rays == 4)
    (out / "cache" / f"{victim.key}.json").unlink()
    again, _, run3 = experiment(parse_experiment(TINY), out, scheduler=scheduler, progress=False,
                                log=lambda m: None)
    assert run3.computed == 1
    assert numbers(again) == numbers(results)


def test_a_rerun_removes_what_a_killed_run_left_half_written(tiny_run, scheduler):
    """A study killed (SIGKILL) while it wrote left hidden temporaries in its report; the next run over the same
    folder removes them."""
    out, results, _, _ = tiny_run
    left = [out / ".pv-abcd1234.html", out / "data" / ".pv-efgh5678.js", out / "plots" / ".pv-mnop3456.png",
            out / "images" / "quad" / ".pv-qrst7890.exr"]
    # a cache another study may share, and a folder the report does not own (another study's report?), are not
    # the report's to clean: their temporaries may be another process's, in the middle of a write
    (out / "other").mkdir(exist_ok=True)
    others = [out / "cache" / ".pv-ijkl9012.npz", out / "other" / ".pv-uvwx1234.exr"]
    for path in left + others:
        path.write_bytes(b"half")
    again, _, run = experiment(parse_experiment(TINY), out, scheduler=scheduler, progress=False, log=lambda m: None)
    assert run.computed == 0 and numbers(again) == numbers(results)
    assert not any(path.exists() for path in left)
    assert all(path.exists() for path in others)
    for path in others:
        path.unlink()
    (out / "other").rmdir()


def test_a_report_folder_another_study_is_writing_is_refused(tmp_path):
    """Two studies writing one folder at once would interleave their files: the second is refused, whole."""
    import fcntl

    out = tmp_path / "busy"
    out.mkdir()
    fd = os.open(out, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # as the other study's process holds it
        with pytest.raises(ProbvisError, match="report folder '.*busy' is being written by another probvis process"):
            experiment(parse_experiment(TINY), out, progress=False, log=lambda m: None)
    finally:
        os.close(fd)
    assert list(out.iterdir()) == []


@pytest.mark.parametrize("damage", ["nan-image", "empty-json", "other-size", "loop", "other-stats", "no-seconds",
                                    "seconds-text", "seconds-nan"])
def test_a_damaged_cache_entry_is_rendered_again(tiny_run, tmp_path, damage, scheduler):
    """An edited entry was trusted (NaN pixels: relmse nan, exit 0) or failed late (a KeyError, a broadcasting
    ValueError, 'folder does not exist' for a link that loops, a KeyError traceback for stats of another shape
    under the same digest, stats without a number the tables read or with one of another type, under a digest
    made again to match; a NaN duration): each now reads as absent and is rendered again."""
    import shutil

    from probvis.io import write_exr

    out, results, _, run = tiny_run
    cache = tmp_path / "cache"
    shutil.copytree(out / "cache", cache)
    victim = next(t for t in run.tasks if t.method.name == "shifted" and t.shadow_rays == 4)
    meta, img = cache / f"{victim.key}.json", cache / f"{victim.key}.exr"
    if damage == "nan-image":
        write_exr(img, np.full((12, 12, 3), np.nan))
    elif damage == "empty-json":
        meta.write_text("{}")
    elif damage == "other-size":
        write_exr(img, np.ones((5, 7, 3)))
    elif damage == "other-stats":
        record = json.loads(meta.read_text())
        meta.write_text(json.dumps({"stats": {"x": 1}, "digest": record["digest"]}))
    elif damage in ("no-seconds", "seconds-text", "seconds-nan"):
        stored = Cache(cache).load(victim.key)  # edited, then given a digest that matches again
        if damage == "no-seconds":
            del stored.stats["seconds"]["total"]
        else:
            stored.stats["seconds"]["total"] = "fast" if damage == "seconds-text" else float("nan")
        meta.write_text(json.dumps({"stats": stored.stats, "digest": runner._digest(stored)}))
    else:
        img.unlink()
        img.symlink_to(img.name)
    again, _, run2 = experiment(parse_experiment(TINY), tmp_path / "r", cache=cache, scheduler=scheduler,
                                progress=False, log=lambda m: None)
    assert run2.computed == 1
    assert numbers(again) == numbers(results)


def test_two_workers_give_the_same_numbers(tiny_run, tmp_path):
    _, results, _, _ = tiny_run
    two, _, run = experiment(parse_experiment(TINY), tmp_path, workers=2, progress=False, log=lambda m: None)
    assert run.computed == 7
    assert numbers(two) == numbers(results)


def test_keys_follow_scene_content_and_settings():
    exp = parse_experiment(TINY)
    refs, cells = plan(exp, load_scenes(exp))
    assert len({t.key for t in cells}) == len(cells) == 6
    other = dict(TINY, resolution=[12, 10])
    refs2, cells2 = plan(parse_experiment(other), load_scenes(parse_experiment(other)))
    assert refs[0].key != refs2[0].key and not {t.key for t in cells} & {t.key for t in cells2}


def test_cells_run_method_after_method_for_each_setting():
    """The cells of one scene, ray count and seed follow each other through the methods, so a busy spell of the
    machine shifts every method's seconds alike, not one method's row."""
    exp = parse_experiment(dict(TINY, seeds=[3, 4]))
    _, cells = plan(exp, load_scenes(exp))
    names = [m["name"] for m in TINY["methods"]]
    for k in range(0, len(cells), len(names)):
        group = cells[k:k + len(names)]
        assert [t.method.name for t in group] == names
        assert len({(t.scene, t.shadow_rays, t.seed) for t in group}) == 1


def test_a_local_cluster_that_cannot_start_is_one_clear_error(monkeypatch):
    """Under `ulimit -f 0` Dask finds no usable temporary folder and raises a RuntimeError from the cause."""
    import dask.distributed

    from probvis.experiments import runner

    def failing(**_):
        try:
            raise FileNotFoundError(errno.ENOENT, "No usable temporary directory found in ['/tmp']")
        except FileNotFoundError as exc:
            raise RuntimeError(f"Cluster failed to start: {exc}") from exc

    monkeypatch.setattr(dask.distributed, "LocalCluster", failing)
    with pytest.raises(ProbvisError, match=r"^cannot start a local Dask cluster: \[Errno 2\] No usable temporary"):
        runner._open_client(1, None)


@pytest.mark.parametrize("files, workers", [(16, 1), (20, 2), (200, 1), (300, 16)])
def test_too_few_open_files_for_a_local_cluster_is_refused_before_it_starts(monkeypatch, files, workers):
    """Sweep 49: under `ulimit -n 20` with two workers Dask's scheduler spun on EMFILE forever, printing tracebacks
    (under 16, one asyncio traceback before the line). The limit is checked before the cluster starts."""
    import dask.distributed

    from probvis.experiments import runner

    def never(**_):
        raise AssertionError("the cluster was started")

    monkeypatch.setattr(dask.distributed, "LocalCluster", never)
    monkeypatch.setattr(runner.resource, "getrlimit", lambda which: (files, files))
    need = max(256, 64 + 16 * workers)
    with pytest.raises(ProbvisError, match=rf"^cannot start a local Dask cluster of {workers} workers?: this process "
                                           rf"may open only {files} files \(ulimit -n\), fewer than the {need} its"):
        runner._open_client(workers, None)


def test_a_soft_open_file_limit_below_the_hard_one_is_raised(monkeypatch):
    """Below the files a cluster needs but with a hard limit above them, the soft limit is raised (as Dask's
    scheduler command does) and the cluster starts."""
    import dask.distributed

    from probvis.experiments import runner

    def started(**_):
        raise RuntimeError("the cluster was started")

    raised = []
    monkeypatch.setattr(dask.distributed, "LocalCluster", started)
    monkeypatch.setattr(runner.resource, "getrlimit", lambda which: (16, 100_000))
    monkeypatch.setattr(runner.resource, "setrlimit", lambda which, limits: raised.append(limits))
    with pytest.raises(ProbvisError, match="^cannot start a local Dask cluster: the cluster was started"):
        runner._open_client(2, None)
    assert raised == [(256, 100_000)]


def test_unreachable_scheduler_is_one_clear_error(tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # closed again when the block ends: nothing listens there
    said = []
    with pytest.raises(ProbvisError, match=f"cannot reach the Dask scheduler at tcp://127.0.0.1:{port}"):
        experiment(parse_experiment(TINY), tmp_path / "rep", scheduler=f"tcp://127.0.0.1:{port}", progress=False,
                   log=said.append)
    assert said == []  # named before the plan's progress line
    assert not (tmp_path / "rep").exists()  # no empty cache folder left behind
    with pytest.raises(ProbvisError, match="out must be the report's folder"):
        experiment(parse_experiment(TINY), None)


@pytest.mark.parametrize("peer, message", [
    ("silent", "accepted the connection but did not answer within 0.5 s as a Dask scheduler does"),
    ("text", r"is not a Dask scheduler \(it answered b'HTTP/1.0'\)"),
    ("closes", "is not a Dask scheduler .it closed the connection without a word."),
])
def test_a_peer_that_is_not_a_dask_scheduler_is_named_before_the_plan(tmp_path, monkeypatch, peer, message):
    """Dask's client hangs on a peer that never greets it (its own timeout does not cover that) and reads a
    text answer as a frame's length (a false out-of-memory error); the address is refused first."""
    monkeypatch.setattr(runner, "HANDSHAKE_SECONDS", 0.5)
    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen(1)
        done = threading.Event()

        def serve():
            conn, _ = srv.accept()
            with conn:
                if peer == "text":
                    conn.sendall(b"HTTP/1.0 200 OK\r\n\r\nhello")
                if peer == "silent":
                    done.wait(10)

        server = threading.Thread(target=serve, daemon=True)
        server.start()
        said = []
        address = f"tcp://127.0.0.1:{srv.getsockname()[1]}"
        with pytest.raises(ProbvisError, match=message):
            experiment(parse_experiment(TINY), tmp_path / "rep", scheduler=address, progress=False, log=said.append)
        done.set()
        server.join(10)
    assert said == [] and not (tmp_path / "rep").exists()


@pytest.mark.parametrize("scheduler", ["", "  "])
def test_an_empty_scheduler_is_refused_not_replaced_by_a_local_cluster(tmp_path, scheduler):
    with pytest.raises(ProbvisError, match="scheduler must be an address .* got an empty one"):
        experiment(parse_experiment(TINY), tmp_path / "rep", scheduler=scheduler, progress=False)


def test_a_transport_without_its_settings_is_one_line(monkeypatch):
    import dask.distributed

    def tls_without_context(address, timeout):
        raise TypeError("TLS expects a `ssl_context` argument of type ssl.SSLContext")

    monkeypatch.setattr(dask.distributed, "Client", tls_without_context)
    with pytest.raises(ProbvisError, match=r"^cannot connect to the Dask scheduler at tls://h:1: TypeError: TLS "
                                           r"expects .*\(tls:// needs the transport's settings"):
        runner._open_client(1, "tls://h:1")


def test_full_disk_while_writing_the_report_keeps_the_renders(tiny_run, tmp_path, monkeypatch):
    out, results, _, run = tiny_run

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(report_module.Report, "_csv", full)
    with pytest.raises(ProbvisError, match="cannot write the report to .*No space left on device"):
        experiment(parse_experiment(TINY), tmp_path / "deeper" / "report", cache=out / "cache", progress=False,
                   log=lambda m: None)
    cache = Cache(out / "cache")
    assert all(cache.has(t.key) for t in run.tasks)
    assert not (tmp_path / "deeper").exists()  # no empty skeleton of a report (images/, plots/, data/) is left


def test_a_stop_signal_while_the_report_is_written_leaves_a_complete_study(tiny_run, tmp_path, monkeypatch):
    """SIGTERM while the report was written waited for the whole report, then said 'interrupted, run the same
    command to resume' (exit 130) though nothing was left to do: the study completes and says so."""
    import signal

    out, results, _, _ = tiny_run
    csv = report_module.Report._csv

    def signalled(self, *args, **kwargs):  # what SIGTERM does here: the deferral's handler records it
        handler = signal.getsignal(signal.SIGTERM)
        assert callable(handler), "the report is written with stop signals deferred"
        handler(signal.SIGTERM, None)
        return csv(self, *args, **kwargs)

    monkeypatch.setattr(report_module.Report, "_csv", signalled)
    again, index, run = experiment(parse_experiment(TINY), tmp_path / "report", cache=out / "cache", progress=False,
                                   log=lambda m: None)
    assert index.is_file() and (tmp_path / "report" / "results.csv").is_file() and run.computed == 0
    assert numbers(again) == numbers(results)


def test_a_report_folder_under_a_file_is_named_as_such(tmp_path):
    """`-o afile/rep` was 'cannot create cache folder afile/rep/cache: Not a directory', naming a folder the user
    never gave."""
    (tmp_path / "afile").write_text("x")
    with pytest.raises(ProbvisError, match="report folder '.*afile/rep' cannot be made: '.*afile' is a file"):
        experiment(parse_experiment(TINY), tmp_path / "afile" / "rep", progress=False, log=lambda m: None)


@pytest.mark.parametrize("name, content, message", [
    ("index.html", "<html><title>my site</title></html>", "holds an index.html that is not a probvis report"),
    ("results.csv", "mine\n", "holds 'results.csv' but no probvis report .* give -o a new folder"),
])
def test_a_folder_holding_files_of_the_user_s_own_is_not_overwritten(tiny_run, tmp_path, name, content, message):
    """`-o` naming a web site's folder, or one of the user's own results.csv, replaced those files without a
    word; a report's own folder is written again (resumed)."""
    out, _, _, _ = tiny_run
    site = tmp_path / "site"
    site.mkdir()
    (site / name).write_text(content)
    with pytest.raises(ProbvisError, match=message):
        experiment(parse_experiment(TINY), site, cache=out / "cache", progress=False, log=lambda m: None)
    assert (site / name).read_text() == content
    _, index, run = experiment(parse_experiment(TINY), out, progress=False, log=lambda m: None)
    assert index.is_file() and run.computed == 0


def test_another_study_s_report_is_replaced_with_a_warning_and_a_lost_index_names_the_cache(tiny_run, tmp_path):
    """A second study run into a first one's folder replaced its report without a word; a report whose index.html
    was deleted was refused with advice ("give -o a new folder") that would have lost its cached renders."""
    out, _, _, _ = tiny_run
    other = tmp_path / "other"
    other.mkdir()
    (other / "index.html").write_text("<!doctype html>\n<html lang=en><head><meta charset=utf-8><title>probvis "
                                      "experiment: first &amp; best</title>")
    with pytest.warns(UserWarning, match=re.escape(f"'{other}' holds the report of study 'first & best': this one, "
                                                   "'tiny', replaces it (give -o another folder to keep both)")):
        experiment(parse_experiment(TINY), other, cache=out / "cache", progress=False, log=lambda m: None)
    lost = tmp_path / "lost"
    (lost / "cache").mkdir(parents=True)
    (lost / "results.csv").write_text("old\n")
    with pytest.raises(ProbvisError, match=re.escape(f"(to reuse the renders cached in '{lost / 'cache'}', add --cache "
                                                     f"{lost / 'cache'})")):
        experiment(parse_experiment(TINY), lost, progress=False, log=lambda m: None)


def test_a_rendered_reference_noisier_than_the_cells_is_warned_of(tmp_path):
    """A reference of 1 x 1 samples judging cells of 1 x 2 ran without a word, its own noise most of the relMSE."""
    from probvis.experiments.config import reference_noise_problem

    noisy = parse_experiment({**TINY, "spp": 1, "reference": {"spp": 1, "shadow_rays": 2}})
    assert reference_noise_problem(noisy) == (
        "experiment 'tiny': the rendered reference takes 1 x 2 samples a pixel, fewer than the largest cell's 1 x 4: "
        "the cells' relMSE then measures mostly the reference's own noise; give [reference] spp and shadow_rays many "
        "times the cells'")
    assert reference_noise_problem(parse_experiment(TINY)) is None  # 4 x 16 against 2 x 4
    with pytest.warns(UserWarning, match="fewer than the largest cell's 1 x 4"):
        experiment(noisy, tmp_path / "r", progress=False, log=lambda m: None)


def test_methods_that_match_the_reference_plot_without_warnings(tiny_run, tmp_path):
    """relMSE 0 (exact methods rendering the reference's own image) has no place on a log axis: left out, not
    warned about. matplotlib warns once a log axis holds only such values (here the target line's)."""
    import dataclasses
    import warnings

    _, results, _, run = tiny_run
    summary = [dict(r, relmse=0.0) for r in results.summary]
    zero = dataclasses.replace(results, summary=summary)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        report_module.write_report(parse_experiment(TINY), run, zero, tmp_path / "report")
    assert (tmp_path / "report" / "plots" / "quad-convergence.png").is_file()


def test_a_pfm_reference_is_read_as_an_exr_one(tmp_path):
    """A reference in PFM (linear radiance, as `probvis render -o ref.pfm` writes it) was refused as 'not an EXR
    image'; its relMSE is the EXR reference's."""
    from probvis.io import write_exr
    from probvis.io.image import write_pfm

    ref = probvis.render("quad-shadow", spp=8, shadow_rays=4, resolution=(12, 12), seed=9).image
    write_exr(tmp_path / "ref.exr", ref)
    write_pfm(tmp_path / "ref.pfm", ref)
    errors = []
    for name in ("ref.exr", "ref.pfm"):
        doc = dict(TINY, scenes=[{"name": "quad", "source": "quad-shadow", "reference": str(tmp_path / name)}])
        results, _, _ = experiment(parse_experiment(doc), tmp_path / name.replace(".", "-"), progress=False,
                                   log=lambda m: None)
        errors.append(sorted(c["relmse"] for c in results.cells))
    assert errors[0] == errors[1] and len(errors[0]) > 0


def test_reference_file_of_the_wrong_size_is_named(tmp_path):
    from probvis.io import write_exr

    write_exr(tmp_path / "ref.exr", np.zeros((5, 5, 3)))
    doc = dict(TINY, scenes=[{"name": "quad", "source": "quad-shadow", "reference": str(tmp_path / "ref.exr")}])
    with pytest.raises(ProbvisError, match="reference .*ref.exr is 5x5, the scene renders 12x12"):
        experiment(parse_experiment(doc), tmp_path / "r", progress=False, log=lambda m: None)



def test_a_method_that_cannot_fit_in_memory_is_refused_before_any_render(tmp_path):
    """It was refused only when its cells came up, after the reference's and every other method's renders, and named
    the command line's --photons."""
    methods = TINY["methods"][:2] + [{"name": "hungry", "visibility": "probvis", "options": {"photons": 10 ** 9}}]
    with pytest.raises(ProbvisError, match=r"scene 'quad', method 'hungry', 1 shadow rays: this render needs about "
                       r".* GiB \(photons .*\) but .* are available: lower options.photons"):
        experiment(parse_experiment(dict(TINY, methods=methods)), tmp_path / "r", progress=False, log=lambda m: None)
    assert not (tmp_path / "r").exists()

@pytest.mark.parametrize("content", [b"garbage, not an image", None], ids=["garbage", "wrong-size"])
def test_bad_references_are_found_before_any_render(tmp_path, content):
    from probvis.io import write_exr

    if content is None:
        write_exr(tmp_path / "ref.exr", np.zeros((5, 5, 3)))
    else:
        (tmp_path / "ref.exr").write_bytes(content)
    doc = dict(TINY, scenes=[{"name": "quad", "source": "quad-shadow", "reference": str(tmp_path / "ref.exr")}])
    with pytest.raises(ProbvisError, match="scene 'quad': reference"):
        experiment(parse_experiment(doc), tmp_path / "r", progress=False, log=lambda m: None)
    assert not list((tmp_path / "r").glob("**/*.json")), "no cell may be rendered first"


@pytest.mark.parametrize("value", [0.0, -0.5, 1e35])
def test_references_that_are_no_radiance_are_refused(tmp_path, value):
    """An all-black, negative or overflowing reference was accepted, and every relMSE measured against it."""
    from probvis.io import write_exr

    img = np.full((12, 12, 3), 0.2)
    img[3, 4] = value if value else 0.2
    write_exr(tmp_path / "ref.exr", img if value else np.zeros((12, 12, 3)))
    doc = dict(TINY, scenes=[{"name": "quad", "source": "quad-shadow", "reference": str(tmp_path / "ref.exr")}])
    with pytest.raises(ProbvisError, match="a reference is converged radiance, non-negative, not all black"):
        experiment(parse_experiment(doc), tmp_path / "r", progress=False, log=lambda m: None)


def test_a_biased_reference_estimator_is_refused():
    with pytest.raises(ProbvisError, match="reference.visibility: 'ratio' is biased"):
        parse_experiment(dict(TINY, reference={"visibility": "ratio"}))


def test_a_report_folder_that_is_a_file_is_named(tmp_path):
    (tmp_path / "taken").write_text("x")
    with pytest.raises(ProbvisError, match="report folder .*taken' is a file"):
        experiment(parse_experiment(TINY), tmp_path / "taken", progress=False, log=lambda m: None)


def test_an_estimator_s_bug_is_named_not_blamed_on_the_cluster(tmp_path):
    (tmp_path / "buggy.py").write_text(
        "from probvis.visibility import VisibilityEstimator\n"
        "class Buggy(VisibilityEstimator):\n    name = 'buggy'\n    summary = 'divides by zero'\n"
        "    def evaluate(self, query):\n        return 1 / 0\n")
    doc = dict(TINY, methods=[{"name": "buggy", "visibility": f"{tmp_path / 'buggy.py'}:Buggy", "baseline": True}])
    with pytest.raises(ProbvisError) as exc:
        experiment(parse_experiment(doc), tmp_path / "r", progress=False, log=lambda m: None)
    text = str(exc.value)
    assert "ZeroDivisionError" in text and "rerunning will not help" in text and "Dask" not in text


def test_report_names_no_file_system_holds_are_refused_before_rendering(tmp_path):
    """A 300-character scene name rendered every cell, then failed with 'File name too long', leaving an
    unfinished report; an `images` folder that is a link looping to itself was 'File exists'."""
    doc = dict(TINY, scenes=[{"name": "q" * 300, "source": "quad-shadow"}])
    with pytest.raises(ProbvisError, match="makes its file name 'qqq.*' 300 bytes long, more than file systems hold"):
        experiment(parse_experiment(doc), tmp_path / "r", progress=False, log=lambda m: None)
    assert not (tmp_path / "r").exists()
    (tmp_path / "s").mkdir()
    (tmp_path / "s" / "images").symlink_to("images")
    with pytest.raises(ProbvisError, match="images', where the report keeps a folder, is a symbolic link that loops"):
        experiment(parse_experiment(TINY), tmp_path / "s", progress=False, log=lambda m: None)
    assert sorted(p.name for p in (tmp_path / "s").iterdir()) == ["images"]


def test_a_report_that_would_replace_a_file_a_scene_reads_is_refused_before_rendering(tmp_path):
    """With -o the scene's own folder, the report's image of a method replaced the scene's texture of the same
    name, exit 0 (later renders read the report's image as the texture)."""
    from tests.conftest import sensor, write_scene

    (tmp_path / "images" / "tex").mkdir(parents=True)
    texture = tmp_path / "images" / "tex" / "exact-1.png"
    texture.write_bytes(ASSET_PNG)
    scene = write_scene(tmp_path / "s.xml", sensor() + "<emitter type='point'><point name='position' x='0' y='0' "
                        "z='2'/></emitter><shape type='rectangle'><bsdf type='diffuse'><texture type='bitmap' "
                        "name='reflectance'><string name='filename' value='images/tex/exact-1.png'/></texture>"
                        "</bsdf></shape>")
    doc = dict(TINY, scenes=[{"name": "tex", "source": str(scene)}], methods=[TINY["methods"][0]])
    with pytest.raises(ProbvisError, match=r"it would replace '.*exact-1.png', which scene 'tex' reads; give -o "
                                           "another folder"):
        experiment(parse_experiment(doc), tmp_path, cache=tmp_path.parent / "c", progress=False, log=lambda m: None)
    assert texture.read_bytes() == ASSET_PNG and not (tmp_path.parent / "c").exists()


def test_report_file_names_are_unique_per_scene():
    from probvis.experiments.config import file_stem

    # a name that looks like a changed one (sweep 49: 'a_b-3ec69c' was the file name of 'a/b', and its own)
    names = ["x/y", "x_y", "x y", "é", "e", "a/b", file_stem("a/b"), "a_b-abcdef", "a_b-ABCDEF"]
    stems = [file_stem(n) for n in names]
    assert len(set(stems)) == len(names) and file_stem("city-1_a") == "city-1_a"
    assert file_stem("a_b-ABCDEF") == "a_b-ABCDEF" and file_stem(file_stem("a/b")) != file_stem("a/b")
    assert all(s.isascii() and "/" not in s for s in stems)


@pytest.mark.parametrize("kind", ["scenes", "methods"])
def test_names_whose_report_files_collide_are_refused(kind):
    """Two names whose hashes agree in the six digits the file name keeps (U+0C0C and U+1C34 between a and b):
    refused before any render, not one's images and viewer data replaced by the other's."""
    from probvis.experiments.config import file_stem

    for one, two in (("a\u0c0cb", "a\u1c34b"), ("City", "city")):  # the second: a file system ignoring case
        assert file_stem(one).casefold() == file_stem(two).casefold()
        entries = [dict(TINY[kind][0], name=one), dict(TINY[kind][0], name=two)]
        with pytest.raises(ProbvisError, match=f"{kind[:-1]} names '{one}' and '{two}' give the same file name "
                                               f"'{file_stem(two)}' in the report: rename one"):
            parse_experiment(dict(TINY, **{kind: entries}))


def test_an_existing_scheduler_gives_the_same_numbers(tiny_run, tmp_path):
    from dask.distributed import LocalCluster

    _, results, _, _ = tiny_run
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        other, _, run = experiment(parse_experiment(TINY), tmp_path, scheduler=cluster.scheduler_address,
                                   progress=False, log=lambda m: None)
    assert run.computed == 7
    assert numbers(other) == numbers(results)


def test_a_scheduler_without_workers_is_named(tmp_path, monkeypatch):
    """It was reported as 'with 1 worker', then failed after a wait with Dask's 'No valid workers found'."""
    from dask.distributed import LocalCluster

    monkeypatch.setattr(runner, "WORKER_WAIT_SECONDS", 1)
    with LocalCluster(n_workers=0, processes=False, dashboard_address=None) as cluster:
        with pytest.raises(ProbvisError, match=r"has no workers \(1 s waited\): start some \(`dask worker"):
            experiment(parse_experiment(TINY), tmp_path / "rep", scheduler=cluster.scheduler_address,
                       progress=False, log=lambda m: None)


def test_sigterm_stops_the_study_keeping_finished_renders(tmp_path):
    """A batch system's SIGTERM interrupts like Ctrl-C: one line, exit 130, finished renders cached."""
    import subprocess
    import sys
    import time

    study = tmp_path / "long.toml"
    study.write_text('spp = 1\nshadow_rays = [1, 2, 3, 4, 5, 6, 7, 8]\nseeds = [0, 1, 2, 3]\nresolution = [24, 24]\n'
                     '[reference]\nspp = 1\nshadow_rays = 1\n'
                     '[[scenes]]\nname = "quad"\nsource = "quad-shadow"\n'
                     '[[methods]]\nname = "exact"\nvisibility = "exact"\n')
    proc = subprocess.Popen([sys.executable, "-m", "probvis.cli", "experiment", str(study), "-o", str(tmp_path / "r"),
                             "-q"], stderr=subprocess.PIPE, text=True)
    cache = tmp_path / "r" / "cache"
    # wait for the first finished render; a cold Numba cache on a loaded 2-core machine can take minutes
    deadline = time.monotonic() + 600
    while not list(cache.glob("*.json")) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    assert list(cache.glob("*.json")) or proc.poll() is not None, "no render finished within 600 s"
    proc.terminate()
    _, err = proc.communicate(timeout=60)
    if proc.returncode == 0:
        pytest.skip("the study finished before the signal arrived")
    assert proc.returncode == 130, err
    assert "interrupted; finished renders are kept in" in err and "Traceback" not in err
    finished = len(list(cache.glob("*.json")))
    assert finished >= 1 and not list(cache.glob(".*"))
    again = subprocess.run([sys.executable, "-m", "probvis.cli", "experiment", str(study), "-o", str(tmp_path / "r"),
                            "-q"], capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert f"{33 - finished} renders computed" in again.stdout
    more = subprocess.run([sys.executable, "-m", "probvis.cli", "experiment", str(study), "-o", str(tmp_path / "r"),
                           "-q", "--seeds", "3,4"], capture_output=True, text=True, timeout=300)
    assert more.returncode == 0, more.stderr
    assert "8 renders computed, 8 of 16 cells from the cache" in more.stdout  # seed 3 cached, seed 4 new
    bad = subprocess.run([sys.executable, "-m", "probvis.cli", "experiment", str(study), "--seeds", "1,1"],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "distinct seeds" in bad.stderr


def test_two_seeds_give_a_bias_column_and_biased_shortcuts_are_labelled(tmp_path, scheduler):
    study = {
        "name": "bias", "spp": 2, "shadow_rays": [4], "seeds": [0, 1], "resolution": [48, 48],
        "reference": {"spp": 16, "shadow_rays": 16},
        "scenes": [{"name": "canopy", "source": "canopy"}],
        "methods": [{"name": "exact", "visibility": "exact"},
                    {"name": "om-off", "visibility": "occlusion-map",
                     "options": {"penumbra": "list", "photons": 20000, "verify": "off"}},
                    {"name": "om", "visibility": "occlusion-map", "options": {"penumbra": "list", "photons": 20000}}],
    }
    results, index, _ = experiment(parse_experiment(study), tmp_path, scheduler=scheduler, progress=False,
                                   log=lambda m: None)
    row = {r["method"]: r for r in results.summary}
    assert row["exact"]["bias_ratio"] < 2.5 and row["om"]["bias_ratio"] < 2.5
    assert row["om-off"]["bias_ratio"] > 10 and row["om-off"]["biased"] and not row["om"]["biased"]
    assert "(biased)" in index.read_text() and "(biased)" in (tmp_path / "results.md").read_text()


def test_timing_repeats_take_the_fastest_and_flag_disagreement(tmp_path, scheduler):
    study = dict(TINY, timing_repeats=3, shadow_rays=[1])
    results, _, run = experiment(parse_experiment(study), tmp_path, scheduler=scheduler, progress=False,
                                 log=lambda m: None)
    for r in results.cells:
        assert len(r["seconds_repeats"]) == 3 and r["seconds"] == min(r["seconds_repeats"])
        spread = (max(r["seconds_repeats"]) - r["seconds"]) / r["seconds"]
        assert r["repeats_disagree"] == (spread > 0.25)
    assert "fastest of 3 repeats" in (tmp_path / "index.html").read_text()


def test_each_repeat_s_render_seconds_leave_out_its_own_load_and_bvh(monkeypatch):
    """A repeat's render seconds subtract its own scene load and BVH, not the last repeat's: a heavy scene's
    BVH time varies by more than a short render takes."""
    import probvis.integrator
    from probvis.experiments.runner import Timing, render_task

    class Fake:
        image = np.zeros((2, 2, 3))

        def __init__(self, total, bvh):
            self.stats = {"seconds": {"total": total, "compile": 0.0, "load": 0.25, "bvh": bvh}}
            self.aovs = {"triangle_tests": np.zeros((2, 2))}

    runs = iter([Fake(2.0, 1.5), Fake(1.75, 1.375), Fake(2.5, 2.125)])
    monkeypatch.setattr(probvis.integrator, "render", lambda *a, **k: next(runs))
    stats, _, _ = render_task(None, "exact", {}, 1, 1, 0, 1, Timing(3))
    assert stats["seconds"]["repeats"] == [2.0, 1.75, 2.5]
    assert stats["seconds"]["repeats_render"] == [0.25, 0.125, 0.125]


def test_timing_seconds_stop_the_repeats_once_the_renders_took_that_long(tmp_path, scheduler):
    study = dict(TINY, timing_repeats=3, timing_seconds=1e-6, shadow_rays=[1])
    results, _, run = experiment(parse_experiment(study), tmp_path, scheduler=scheduler, progress=False,
                                 log=lambda m: None)
    assert all(len(r["seconds_repeats"]) == 1 for r in results.cells)
    assert "up to 3 repeats (fewer once they took 1e-06 s together)" in (tmp_path / "results.md").read_text()


def test_a_reference_equal_to_a_render_gives_a_report(tmp_path):
    """A reference file holding a cell's own image: relMSE 0, efficiency infinite and its ratio to the baseline's
    undefined; shown as such, and results.json holds null there (a NaN crashed the report after the renders)."""
    from probvis.cli import main

    assert main(["render", "quad-shadow", "-D", "res=8", "--spp", "1", "--shadow-rays", "1", "--threads", "1",
                 "-o", str(tmp_path / "r.exr"), "-q"]) == 0
    study = tmp_path / "same.toml"
    study.write_text('spp = 1\nshadow_rays = [1]\nseeds = [0]\nresolution = [8, 8]\n'
                     '[[scenes]]\nname = "q"\nsource = "quad-shadow"\nreference = "r.exr"\n'
                     '[[methods]]\nname = "exact"\nvisibility = "exact"\n')
    assert main(["experiment", str(study), "-o", str(tmp_path / "rep"), "-q"]) == 0
    doc = json.loads((tmp_path / "rep" / "results.json").read_text())
    assert "| q | exact |" in (tmp_path / "rep" / "results.md").read_text()
    assert json.dumps(doc, allow_nan=False)


def test_a_worker_s_warnings_are_said_by_the_driver(tmp_path):
    """A warning raised in a worker process was printed there as Python's two-line warning (file, line and source);
    it now travels with the render's stats and the driver says it once, naming scene and method."""
    from tests.conftest import sensor, write_scene

    below = ('<shape type="rectangle"/><emitter type="directional"><vector name="direction" z="1"/>'
             '<rgb name="irradiance" value="2"/></emitter>')
    path = write_scene(tmp_path / "dark.xml", sensor() + below)
    study = {"name": "dark", "spp": 1, "shadow_rays": [1], "seeds": [0], "resolution": [8, 8],
             "reference": {"spp": 2, "shadow_rays": 2}, "scenes": [{"name": "q", "source": str(path)}],
             "methods": [{"name": "ex", "visibility": "exact"}]}
    with pytest.warns(UserWarning, match=r"^(q / (ex|reference): the|scene q: the reference) image is black") as caught:
        experiment(parse_experiment(study), tmp_path / "r", progress=False, log=lambda m: None)
    for name in ("ex", "reference"):
        assert sum(f"q / {name}: the image is black" in str(w.message) for w in caught) == 1
    assert sum("scene q: the reference image is black, so every method's relMSE is 0" in str(w.message)
               for w in caught) == 1


def test_a_cache_under_a_dangling_link_names_the_link(tmp_path):
    """A report folder that is a link to nowhere said "File exists"."""
    (tmp_path / "rep").symlink_to(tmp_path / "nowhere")
    with pytest.raises(ProbvisError, match=r"cannot create cache folder '.*rep/cache': '.*rep' is a symbolic link to "
                                           r"'.*nowhere', which does not exist"):
        Cache(tmp_path / "rep" / "cache")


def test_renders_are_submitted_a_few_per_worker_at_a_time(monkeypatch):
    """A study of thousands of cells keeps only IN_FLIGHT_PER_WORKER renders per worker submitted and unfinished,
    so the scheduler's and the driver's memory do not grow with the study; every render is still stored."""
    import dask.distributed
    from types import SimpleNamespace

    in_flight, peak, stored = set(), [0], []

    class Future:
        def __init__(self, value):
            self.value = value

        def result(self):
            return self.value

        def release(self):
            in_flight.discard(self)

    class Client:
        def scheduler_info(self, n_workers):
            return {"workers": {"a": None, "b": None}}

        def scatter(self, scene, broadcast):
            return scene

        def submit(self, *args, **kwargs):
            f = Future(({"warnings": []}, None, None))
            in_flight.add(f)
            peak[0] = max(peak[0], len(in_flight))
            return f

    def wait(futures, timeout, return_when):  # the oldest one finishes
        return {futures[0]}, set(futures[1:])

    monkeypatch.setattr(dask.distributed, "wait", wait)
    method = SimpleNamespace(visibility="exact", options={}, name="exact")
    todo = [SimpleNamespace(scene="s", method=method, spp=1, shadow_rays=1, seed=k, key=f"k{k}", reference=k == 0)
            for k in range(50)]
    cache = SimpleNamespace(store=lambda key, render: stored.append(key))
    runner._run_tasks(Client(), 2, None, todo, {"s": None}, cache, False, lambda m: None, lambda: None)
    assert peak[0] == 2 * runner.IN_FLIGHT_PER_WORKER
    assert stored == [t.key for t in todo]


def test_a_renamed_method_s_files_leave_the_report(tiny_run, tmp_path):
    """Images an earlier report wrote that the new one does not (a method renamed) are removed; other files in the
    report's folders stay, and so do files outside it that a tampered list names."""
    import shutil

    out, *_ = tiny_run
    folder = tmp_path / "r"
    shutil.copytree(out, folder)
    old = folder / "images" / "quad" / "shifted-4.png"
    assert old.is_file()
    (folder / "images" / "quad" / "mine.png").write_bytes(b"x")
    outside = tmp_path / "outside.png"
    outside.write_bytes(b"x")
    doc = json.loads((folder / "results.json").read_text())
    doc["report_files"] += ["../outside.png", "images/../../outside.png", str(outside)]
    (folder / "results.json").write_text(json.dumps(doc))
    study = dict(TINY, methods=[*TINY["methods"][:2], dict(TINY["methods"][2], name="shifted2")])
    _, _, run = experiment(parse_experiment(study), folder, progress=False, log=lambda m: None)
    assert run.computed == 0  # the same renders, from the cache
    assert not old.exists() and (folder / "images" / "quad" / "shifted2-4.png").is_file()
    assert outside.is_file() and (folder / "images" / "quad" / "mine.png").is_file()
    assert "images/quad/shifted2-4.png" in json.loads((folder / "results.json").read_text())["report_files"]


def test_a_study_under_numba_num_threads_gives_each_render_no_more(tmp_path):
    """With NUMBA_NUM_THREADS=1 in the environment every render of a study failed: each worker was given the
    machine's cores (2 here), which no render may use then."""
    import subprocess
    import sys

    if (os.cpu_count() or 1) < 2:
        pytest.skip("one core: a worker gets one thread with or without NUMBA_NUM_THREADS")

    study = tmp_path / "one.toml"
    study.write_text('spp = 1\nshadow_rays = [1]\nseeds = [0]\nresolution = [8, 8]\n[reference]\nspp = 1\n'
                     'shadow_rays = 1\n[[scenes]]\nname = "quad"\nsource = "quad-shadow"\n'
                     '[[methods]]\nname = "exact"\nvisibility = "exact"\n')
    r = subprocess.run([sys.executable, "-m", "probvis.cli", "experiment", str(study), "-o", str(tmp_path / "r")],
                       capture_output=True, text=True, timeout=300, env={**os.environ, "NUMBA_NUM_THREADS": "1"})
    assert r.returncode == 0, r.stderr
    assert "1 worker x 1 thread" in r.stderr


def test_a_bar_in_a_name_keeps_the_markdown_tables_columns(tmp_path, scheduler):
    """A method named 'exact|fast' added a column to its rows of results.md; its '|' is escaped."""
    doc = dict(TINY, shadow_rays=[1], resolution=[8, 8], scenes=[{"name": "q|uad", "source": "quad-shadow"}],
               methods=[{"name": "exact|fast", "visibility": "exact", "baseline": True}])
    experiment(parse_experiment(doc), tmp_path / "r", scheduler=scheduler, progress=False, log=lambda m: None)
    text = (tmp_path / "r" / "results.md").read_text()
    assert "exact\\|fast" in text and "q\\|uad" in text
    tables = [t.splitlines() for t in text.split("\n\n") if t.startswith("|")]
    assert len(tables) >= 3
    for table in tables:  # every row has its header's columns
        assert len({row.replace("\\|", "").count("|") for row in table}) == 1, table
