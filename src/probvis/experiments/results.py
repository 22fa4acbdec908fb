"""Per-cell metrics, their per-setting summary over seeds, and per-method time to a target error."""
import json
import statistics
from dataclasses import dataclass

from ..errors import checked_call, expect_record
from ..io.stats import biased_by_choice
from ..visibility import estimator_class
from . import metrics



UNSTEADY = 0.25  # seeds' render times differing by more than this share of their median: a busy machine
# what the tables read from a render's stats: numbers (counts, shares, durations), optional lists of numbers,
# optional tables
_NUMBERS = ("seconds.total", "seconds.compile", "seconds.load", "seconds.bvh", "seconds.prepare", "seconds.render",
            "camera_rays", "shadow_rays", "negative_estimate_share", "negative_pixels.negative_pixel_share",
            "intersection_tests.node", "intersection_tests.triangle", "intersection_tests.shadow.node",
            "intersection_tests.shadow.triangle")
_NUMBER_LISTS = ("seconds.repeats", "seconds.repeats_render")
_TABLES = ("bvh", "estimator", "estimator.tests", "estimator.tests.proxy", "estimator.tests.shells",
           "estimator.verification")
_NUMBER_TABLES = ("estimator.seconds", "estimator.memory_bytes")


def _at(stats, path):
    """The value at a dotted path of nested dicts, None where the path ends early."""
    for key in path.split("."):
        stats = stats.get(key) if isinstance(stats, dict) else None
    return stats


def _number(x):
    """A count, share or duration as stats hold it: finite and not negative."""
    return isinstance(x, (int, float)) and not isinstance(x, bool) and 0 <= x < float("inf")


def stats_readable(stats):
    """Whether a render's stats hold what the tables read, of the types they read (a cache entry written by
    another version of probvis, or edited, may not)."""
    def optional(path, kind, each=None):
        x = _at(stats, path)
        return x is None or (isinstance(x, kind) and (each is None or all(map(each, x))))

    return (isinstance(stats, dict) and all(_number(_at(stats, p)) for p in _NUMBERS)
            and all(optional(p, list, _number) for p in _NUMBER_LISTS) and all(optional(p, dict) for p in _TABLES)
            and all(optional(p, dict) and all(map(_number, (_at(stats, p) or {}).values())) for p in _NUMBER_TABLES))


@dataclass
class Results:
    """`cells`: one row per render; `summary`: rows per (scene, method, shadow rays) over seeds;
    `targets`: per scene the target relMSE and each method's interpolated time and tests to reach it."""

    cells: list
    summary: list
    targets: dict

    def summary_row(self, scene, method, shadow_rays):
        return next((r for r in self.summary if (r["scene"], r["method"], r["shadow_rays"]) ==
                     (scene, method, shadow_rays)), None)


def phases(stats, visibility):
    """Seconds per phase of a render without JIT compile: scene load, BVH build, the estimator's preparation
    and per-batch phases as its class declares them, the rest of its preparation and the rest of rendering."""
    sec = stats["seconds"]
    own = (stats.get("estimator") or {}).get("seconds") or {}
    declared = estimator_class(visibility).phases
    prepare = {p.name: own.get(p.name, 0.0) for p in declared if p.stage == "prepare"}
    batch = {p.name: own.get(p.name, 0.0) for p in declared if p.stage == "batch"}
    out = {"load": sec["load"], "bvh_build": sec["bvh"], **prepare}
    rest = sec["prepare"] - sum(prepare.values())
    if rest > 0 and prepare:
        out["prepare_other"] = rest
    elif not prepare:
        out["prepare"] = sec["prepare"]
    return {**out, **batch, "render": sec["render"] - sum(batch.values())}


def tests_by_geometry(stats):
    """Shadow-ray tests by the geometry tested: node and triangle tests of the scene and of proxies (the
    scene's are the rest of the shadow-ray totals: all of them for estimators that test only the scene) and
    the voxels the walks of the shells' grid and of the volumetric proxies' extinction grid visited."""
    split = (stats.get("estimator") or {}).get("tests") or {}
    shadow = stats["intersection_tests"]["shadow"]
    proxy = {k: int((split.get("proxy") or {}).get(k, 0)) for k in ("node", "triangle")}
    return {"scene": {k: int(shadow[k]) - proxy[k] for k in ("node", "triangle")}, "proxy": proxy,
            "shell_voxels": int((split.get("shells") or {}).get("voxel", 0)),
            "volume_voxels": int((split.get("proxy") or {}).get("voxel", 0))}


def cell_row(task, render, reference, baseline_name, counted="total"):
    """One cell's metrics; its seconds count everything but JIT compilation, or with `counted` "render" only
    the render and the estimator's preparation (not the scene load and BVH every method shares)."""
    s = render.stats
    err = metrics.relmse(render.image, reference)
    sec = s["seconds"]
    if counted == "render":  # each repeat without its own scene load and BVH (they vary from repeat to repeat)
        repeats = sec.get("repeats_render") or [sec["total"] - sec["compile"] - sec["load"] - sec["bvh"]]
    else:
        repeats = sec.get("repeats") or [sec["total"] - sec["compile"]]
    seconds = min(repeats)  # the fastest repeat: what the render costs when the machine lets it
    cpu = s["seconds"].get("cpu_total", 0.0) - s["seconds"].get("cpu_compile", 0.0)
    tests = s["intersection_tests"]["shadow"]["triangle"]
    return {
        "scene": task.scene, "method": task.method.name, "visibility": task.method.visibility,
        "options": json.dumps(task.method.options, sort_keys=True, default=list),
        "baseline": task.method.name == baseline_name, "shadow_rays": task.shadow_rays, "spp": task.spp,
        "seed": task.seed, "seconds": seconds, "cpu_seconds": cpu, "seconds_repeats": repeats,
        "repeats_disagree": (max(repeats) - seconds) / seconds > UNSTEADY if seconds > 0 else False,
        "seconds_phases": phases(s, task.method.visibility),
        "camera_rays": s["camera_rays"],
        "shadow_rays_traced": s["shadow_rays"], "triangle_tests": tests,
        "node_tests": s["intersection_tests"]["shadow"]["node"],
        "triangle_tests_total": s["intersection_tests"]["triangle"],
        "tests_by_geometry": tests_by_geometry(s),
        "estimator_bytes": sum(((s.get("estimator") or {}).get("memory_bytes") or {}).values()),
        "scene_bvh_bytes": s["bvh"].get("bytes", 0),
        "node_tests_total": s["intersection_tests"]["node"],
        "relmse": err, "rmse": metrics.rmse(render.image, reference),
        "negative_pixel_share": s["negative_pixels"]["negative_pixel_share"],
        "biased": biased_by_choice(s),
        "negative_estimate_share": s["negative_estimate_share"],
        "efficiency_time": metrics.efficiency(err, seconds), "efficiency_tests": metrics.efficiency(err, tests),
    }


def _changes(rows, key_fields):
    """Add seconds, tests and efficiency relative to the baseline row with the same `key_fields`."""
    base = {tuple(r[k] for k in key_fields): r for r in rows if r["baseline"]}
    for r in rows:
        b = base.get(tuple(r[k] for k in key_fields))
        r["seconds_change"] = r["seconds"] / b["seconds"] - 1 if b and b["seconds"] else None
        r["tests_change"] = r["triangle_tests"] / b["triangle_tests"] - 1 if b and b["triangle_tests"] else None
        r["efficiency_vs_baseline"] = (r["efficiency_time"] / b["efficiency_time"]
                                       if b and b["efficiency_time"] else None)


def _summarise(cells, bias):
    groups = {}
    for r in cells:
        groups.setdefault((r["scene"], r["method"], r["shadow_rays"]), []).append(r)
    out = []
    for key, rows in groups.items():
        first = rows[0]
        row = {k: first[k] for k in ("scene", "method", "visibility", "options", "baseline", "shadow_rays", "spp",
                                     "biased")}
        row["bias_ratio"] = bias.get(key)
        row["seeds"] = len(rows)
        row["seconds"] = statistics.median(r["seconds"] for r in rows)
        row["cpu_seconds"] = statistics.median(r["cpu_seconds"] for r in rows)
        times = [r["seconds"] for r in rows]
        row["seconds_spread"] = (max(times) - min(times)) / row["seconds"] if row["seconds"] > 0 else 0.0
        row["timing_unsteady"] = (len(rows) > 1 and row["seconds_spread"] > UNSTEADY) or any(
            r["repeats_disagree"] for r in rows)
        row["seconds_phases"] = {k: statistics.median(r["seconds_phases"].get(k, 0.0) for r in rows)
                                 for k in first["seconds_phases"]}
        for k in ("triangle_tests", "node_tests", "relmse", "rmse", "negative_pixel_share", "negative_estimate_share",
                  "estimator_bytes", "scene_bvh_bytes"):
            row[k] = statistics.fmean(r[k] for r in rows)
        row["tests_by_geometry"] = {g: {k: statistics.fmean(r["tests_by_geometry"][g][k] for r in rows)
                                        for k in ("node", "triangle")} for g in ("scene", "proxy")}
        for g in ("shell_voxels", "volume_voxels"):
            row["tests_by_geometry"][g] = statistics.fmean(r["tests_by_geometry"][g] for r in rows)
        row["efficiency_time"] = metrics.efficiency(row["relmse"], row["seconds"])
        row["efficiency_tests"] = metrics.efficiency(row["relmse"], row["triangle_tests"])
        out.append(row)
    return out


def _targets(exp, summary):
    """Per scene: the target relMSE (the experiment's, else the smallest error every method reaches) and each
    method's log-log interpolated seconds and tests to reach it."""
    out = {}
    for spec in exp.scenes:
        curves = {m.name: sorted((r for r in summary if r["scene"] == spec.name and r["method"] == m.name),
                                 key=lambda r: r["shadow_rays"]) for m in exp.methods}
        target = exp.target_relmse
        if target is None:
            target = max(min(r["relmse"] for r in rows) for rows in curves.values())
        out[spec.name] = {"target_relmse": target, "methods": {
            name: {"seconds": metrics.time_to_target([r["seconds"] for r in rows], [r["relmse"] for r in rows], target),
                   "triangle_tests": metrics.time_to_target([r["triangle_tests"] for r in rows],
                                                            [r["relmse"] for r in rows], target)}
            for name, rows in curves.items()}}
    return out


def _bias_ratios(exp, run):
    """Per (scene, method, shadow rays): the block-bias ratio of the first two seeds' images (see
    `metrics.block_bias_ratio`); none with a single seed."""
    if len(exp.seeds) < 2:
        return {}
    images = {(t.scene, t.method.name, t.shadow_rays, t.seed): run.renders[t.key].image for t in run.tasks}
    out = {}
    for spec in exp.scenes:
        noise = run.reference_noise.get(spec.name, 0.0)
        for m in exp.methods:
            for sr in exp.shadow_rays:
                a, b = (images[(spec.name, m.name, sr, s)] for s in exp.seeds[:2])
                out[(spec.name, m.name, sr)] = metrics.block_bias_ratio(a, b, run.reference_images[spec.name],
                                                                        reference_noise=noise)
    return out


@checked_call
def measure(exp, run):
    """Metrics of every cell of a finished run (a `runner.RunSummary`) against its scene's reference."""
    from .config import MADE_BY, Experiment
    from .runner import RunSummary  # the runner reads this module's stats check

    expect_record(exp, Experiment, "exp", MADE_BY)
    expect_record(run, RunSummary, "run", "the RunSummary run_experiment returns")
    cells = [cell_row(t, run.renders[t.key], run.reference_images[t.scene], exp.baseline, exp.seconds)
             for t in run.tasks]
    _changes(cells, ("scene", "shadow_rays", "seed"))
    summary = _summarise(cells, _bias_ratios(exp, run))
    _changes(summary, ("scene", "shadow_rays"))
    return Results(cells, summary, _targets(exp, summary))
