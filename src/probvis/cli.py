"""Command line: `probvis render | info | scenes | tables | experiment`."""
import argparse
import dataclasses
import json
import shlex
import signal
import sys
import warnings
from pathlib import Path

from . import __version__
from .errors import ProbvisError


def _defines(items):
    out = {}
    for item in items or []:
        if "=" not in item:
            raise ProbvisError(f"-D expects name=value, got '{item}'")
        k, v = item.split("=", 1)
        out[k.strip()] = v.strip()
    return out


def _int_at_least(lowest):
    """argparse type: a whole number >= `lowest`."""

    def parse(text):
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got '{text}'") from None
        if v < lowest:
            raise argparse.ArgumentTypeError(f"must be at least {lowest}, got {v}")
        return v

    return parse


def _positive_float(text):
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got '{text}'") from None
    if not v > 0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return v


def _comma_list(text, convert, what):
    """The comma-separated values of `text` converted, or an argparse error naming `what` was expected."""
    try:
        return tuple(convert(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got '{text}'") from None


def _triple(text):
    v = _comma_list(text, float, "three comma-separated numbers")
    if len(v) != 3:
        raise argparse.ArgumentTypeError(f"expected three comma-separated numbers, got '{text}'")
    return v


def _seed_list(text):
    """argparse type: distinct comma-separated whole numbers >= 0."""
    v = _comma_list(text, int, "comma-separated whole numbers")
    if min(v) < 0 or len(set(v)) != len(v):
        raise argparse.ArgumentTypeError(f"expected distinct seeds >= 0, got '{text}'")
    return v


PROBVIS_OPTIONS = ("estimator", "probabilities", "shifts", "power", "grouping", "levels", "cells")
VISIBILITY_OPTIONS = ("photons", "neighbours", "radius", "penumbra", "adaptive", "volumetric") + PROBVIS_OPTIONS


_positive = _int_at_least(1)
_non_negative = _int_at_least(0)


def _parser():
    p = argparse.ArgumentParser(prog="probvis", description="Direct illumination with measurable visibility.")
    p.add_argument("--version", action="version", version=f"probvis {__version__}")
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("render", help="render a scene to EXR/PFM/PNG and report its statistics")
    r.add_argument("scene", help="Mitsuba XML file or built-in scene name (see `probvis scenes`)")
    r.add_argument("-o", "--output", action="append", metavar="OUT",
                   help="output image (.exr, .pfm, .png); repeat for several (default: SCENE.exr)")
    r.add_argument("--spp", type=_positive, help="camera samples per pixel")
    r.add_argument("--shadow-rays", type=_positive, help="emitter samples (shadow rays) per camera sample")
    r.add_argument("-D", dest="defines", action="append", metavar="NAME=VALUE", help="override a <default>")
    r.add_argument("--seed", type=_non_negative, help="random seed (default: the scene's sampler seed)")
    r.add_argument("--visibility", default="exact",
                   help="visibility estimator: exact, occlusion-map, probvis (default: exact)")
    om = r.add_argument_group("occlusion map (--visibility occlusion-map)")
    om.add_argument("--photons", type=_positive, help="photon rays of the first pass (default: 0.5 per camera "
                                                         "sample, at least 100,000)")
    om.add_argument("--neighbours", type=_positive, help="photons looked up per shading point (default 32)")
    om.add_argument("--radius", type=_positive_float, help="look-up radius (default: from the photon density)")
    om.add_argument("--penumbra", choices=("list", "bvh"), help="test penumbra shadow rays against the candidate "
                                                                 "blocker list or the whole BVH (default bvh)")
    om.add_argument("--adaptive", action=argparse.BooleanOptionalAction, default=None,
                    help="aim extra photons at uncertain regions (default off)")
    om.add_argument("--volumetric", action=argparse.BooleanOptionalAction, default=None,
                    help="cull closed meshes' triangles facing away from the light end (list mode; default on)")
    om.add_argument("--case-image", metavar="OUT", help="write the per-pixel case shares (R penumbra, G lit, "
                                                        "B shadowed, grey unknown), one image per emitter")
    pv = r.add_argument_group("probabilistic visibility (--visibility probvis; also takes the occlusion-map options)")
    pv.add_argument("--estimator", choices=("standard", "shifted", "power", "adaptive"),
                    help="decomposition of V = V_A V_B (default standard)")
    pv.add_argument("--probabilities", type=_triple, metavar="P1,P2,P3", help="term probabilities (default 1/3 each)")
    pv.add_argument("--shifts", type=_triple, metavar="A,B,G", help="shifts of the shifted estimator (sum 1)")
    pv.add_argument("--power", type=_positive, help="exponent of the power estimator (default 8)")
    pv.add_argument("--grouping", choices=("solid-angle", "count", "random"), help="A/B split (default solid-angle)")
    pv.add_argument("--levels", type=_positive, help="recursive subdivision depth (default 1: one A/B split)")
    pv.add_argument("--cells", type=_positive, help="groups along the ray whose estimates multiply (default 1)")
    r.add_argument("--clamp-negative", action="store_true",
                   help="clamp negative pixels to zero (biased: too bright on average; the bias is reported)")
    r.add_argument("--stats", metavar="OUT.json", help="write the statistics as JSON")
    r.add_argument("--tests-image", metavar="OUT.exr", help="write per-pixel ray-triangle and ray-node test counts")
    r.add_argument("--threads", type=_positive, help="worker threads (default: all cores)")
    r.add_argument("--exposure", type=float, default=0.0, help="PNG exposure in stops (default 0)")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no summary")

    i = sub.add_parser("info", help="triangles, emitters, bounds and BVH statistics of a scene")
    i.add_argument("scene")
    i.add_argument("-D", dest="defines", action="append", metavar="NAME=VALUE")
    i.add_argument("--json", action="store_true", help="print JSON")

    sub.add_parser("scenes", help="list the built-in scenes")

    t = sub.add_parser("tables", help="per decomposition: term values and variance in the four configurations")
    t.add_argument("--json", action="store_true", help="print JSON")
    t.add_argument("--probabilities", type=_triple, metavar="P1,P2,P3", help="term probabilities (default 1/3)")
    t.add_argument("--shifts", type=_triple, metavar="A,B,G", help="shifts of the shifted decomposition")
    t.add_argument("--power", type=_positive, default=8, help="exponent of the power decomposition (default 8)")

    e = sub.add_parser("experiment", help="run a study (TOML) on Dask and write a browsable report",
                       description="Render every cell (scene x method x shadow rays x seed) of a study, caching "
                                   "each on disk so an interrupted study resumes, and write a report folder.")
    e.add_argument("file", nargs="?", help="experiment TOML file (e.g. experiments/paper.toml)")
    e.add_argument("--quick", action="store_true", help="the built-in quick preset instead of a file")
    e.add_argument("-o", "--output", metavar="DIR", help="report folder (default: experiment-NAME)")
    e.add_argument("--cache", metavar="DIR", help="render cache folder (default: DIR/cache)")
    e.add_argument("--seeds", type=_seed_list, metavar="S1,S2,...", help="render these seeds instead of the file's")
    e.add_argument("--workers", type=_positive, default=1, help="LocalCluster worker processes (default 1)")
    e.add_argument("--scheduler", metavar="ADDRESS", help="use the Dask scheduler at ADDRESS (tcp://host:port)")
    e.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    return p


def _cmd_render(args):
    from .integrator import render
    from .io import check_writable, summary, write_case_images, write_exr, write_image, write_stats

    outputs = args.output or [f"{Path(args.scene).stem}.exr"]
    for path in outputs + [x for x in (args.stats, args.tests_image, args.case_image) if x]:
        check_writable(path)
    if args.tests_image and not args.tests_image.lower().endswith(".exr"):
        raise ProbvisError("--tests-image must be an .exr file")
    options = {k: getattr(args, k) for k in VISIBILITY_OPTIONS if getattr(args, k) is not None}
    if options and args.visibility == "exact":
        raise ProbvisError(f"--{next(iter(options)).replace('_', '-')} does not apply to --visibility exact")
    probvis_only = [k for k in options if k in PROBVIS_OPTIONS]
    if probvis_only and args.visibility != "probvis":
        raise ProbvisError(f"--{probvis_only[0]} applies to --visibility probvis only")
    if args.case_image and args.visibility == "exact":
        raise ProbvisError("--case-image needs a visibility that classifies points (e.g. occlusion-map)")
    result = render(args.scene, spp=args.spp, shadow_rays=args.shadow_rays, seed=args.seed,
                    visibility=args.visibility, visibility_options=options, threads=args.threads,
                    clamp_negative=args.clamp_negative,
                    progress=not args.quiet and sys.stderr.isatty(), **_defines(args.defines))
    for path in outputs:
        write_image(path, result.image, args.exposure)
    if args.tests_image:
        write_exr(args.tests_image, None, channels={"triangle": result.aovs["triangle_tests"],
                                                    "node": result.aovs["node_tests"]})
    written = outputs + [x for x in (args.tests_image,) if x]
    if args.case_image:
        written += write_case_images(args.case_image, result.aovs["cases"])
    if args.stats:
        write_stats(args.stats, result.stats)
        written.append(args.stats)
    if not args.quiet:
        print(summary(result.stats))
        print("wrote       " + ", ".join(written))
    return 0


def _cmd_info(args):
    import numpy as np

    from .accel import build_bvh
    from .lights import build_emitter_sampler
    from .scene import load_scene

    scene = load_scene(args.scene, **_defines(args.defines))
    bvh = build_bvh(scene.triangles)
    es = build_emitter_sampler(scene)
    lo, hi = scene.bounds()
    cam = scene.camera
    info = {
        "scene": scene.name,
        "source": scene.source,
        "triangles": scene.n_triangles,
        "dropped_degenerate_triangles": scene.dropped_degenerate,
        "bounds": {"min": lo.tolist(), "max": hi.tolist()},
        "shapes": [{"name": s.name, "type": s.kind, "triangles": s.n_triangles, "emitter": s.emitter}
                   for s in scene.shapes],
        "emitters": [{"radiance": scene.emitter_radiance[e].tolist(), "area": float(es.emitter_area[e]),
                      "power": float(es.power[e]), "selection_probability": float(es.emitter_pmf[e])}
                     for e in range(scene.n_emitters)],
        "camera": {"width": cam.width, "height": cam.height, "fov_x": cam.fov_x,
                   "origin": cam.to_world[:3, 3].tolist()},
        "spp": scene.spp,
        "shadow_rays_per_sample": scene.shadow_rays,
        "bvh": bvh.stats(),
    }
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    print(f"scene      {info['scene']} ({info['source']})")
    print(f"triangles  {info['triangles']:,}" + (f" ({scene.dropped_degenerate} degenerate dropped)"
                                                if scene.dropped_degenerate else ""))
    print(f"bounds     {np.round(lo, 4).tolist()} .. {np.round(hi, 4).tolist()}")
    print(f"camera     {cam.width}x{cam.height}, fov_x {cam.fov_x:.4g} deg, {scene.spp} spp x "
          f"{scene.shadow_rays} shadow rays")
    for e, em in enumerate(info["emitters"]):
        print(f"emitter {e}  radiance {em['radiance']}, area {em['area']:.4g}, power {em['power']:.4g}, "
              f"p {em['selection_probability']:.3f}")
    b = info["bvh"]
    print(f"bvh        {b['nodes']:,} nodes, {b['leaves']:,} leaves, depth {b['max_depth']}, "
          f"mean leaf {b['mean_leaf_size']:.2f}, SAH cost {b['sah_cost']:.2f}, built in {b['build_seconds']:.3f} s")
    for s in info["shapes"]:
        print(f"shape      {s['name']:<16} {s['type']:<10} {s['triangles']:>8,} triangles"
              + ("  (emitter)" if s["emitter"] >= 0 else ""))
    return 0


def _cmd_scenes(args):
    from .scene import BUILTINS

    for name, (_, text) in BUILTINS.items():
        print(f"{name:<14} {text}")
    return 0


def _cmd_tables(args):
    from .visibility.probvis import power, shifted, standard

    p = args.probabilities or (1 / 3, 1 / 3, 1 / 3)
    try:
        decs = [standard(p), shifted(p, args.shifts or (1 / 3, 1 / 3, 1 / 3)), power(args.power, p)]
    except ValueError as exc:
        raise ProbvisError(str(exc)) from None
    out = [{"decomposition": d.name, "probabilities": d.p.tolist(), "terms": list(d.labels), "rows": d.rows()}
           for d in decs]
    if args.json:
        print(json.dumps(out, indent=1))
        return 0
    for d in out:
        print(f"{d['decomposition']}  (p = {', '.join(f'{x:.4g}' for x in d['probabilities'])})")
        print(f"  {'V_A':>3} {'V_B':>3} {'V_A V_B':>7}  " + "".join(f"{t:>24}" for t in d["terms"])
              + f"{'variance':>12}")
        for r in d["rows"]:
            print(f"  {r['VA']:>3} {r['VB']:>3} {r['product']:>7}  " + "".join(f"{v:>24.6g}" for v in r["values"])
                  + f"{r['variance']:>12.6g}")
        print()
    return 0


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def _cmd_experiment(args):
    from .experiments import experiment, load_experiment, quick_experiment

    if args.quick == bool(args.file):
        raise ProbvisError("give an experiment file or --quick (not both)")
    if args.scheduler and args.workers != 1:
        raise ProbvisError("--workers applies to the embedded LocalCluster, not to --scheduler")
    exp = quick_experiment() if args.quick else load_experiment(args.file)
    if args.seeds:
        exp = dataclasses.replace(exp, seeds=args.seeds)
    out = Path(args.output or f"experiment-{exp.name}")
    command = "probvis " + shlex.join(args.argv)
    previous = signal.signal(signal.SIGTERM, _interrupt)  # a batch system's "stop": same as Ctrl-C
    try:
        _, index, run = experiment(exp, out, args.cache, args.workers, args.scheduler, not args.quiet, command)
    except KeyboardInterrupt:
        print(f"probvis: interrupted; finished renders are kept in {args.cache or out / 'cache'}, "
              f"run the same command to resume", file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)
    print(f"{run.computed} renders computed, {run.cells_cached} of {len(run.tasks)} cells from the cache; "
          f"report: {index}")
    return 0


def _warning_line(message, category, filename, lineno, file=None, line=None):
    print(f"probvis: warning: {message}", file=sys.stderr)


def main(argv=None):
    args = _parser().parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    warnings.showwarning = _warning_line
    try:
        return {"render": _cmd_render, "info": _cmd_info, "scenes": _cmd_scenes,
                "tables": _cmd_tables, "experiment": _cmd_experiment}[args.command](args)
    except ProbvisError as exc:
        print(f"probvis: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("probvis: interrupted, nothing written", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
