"""Command line: `probvis render | info | scenes | estimators | tables | experiment`."""
import sys

if __name__ == "__main__":  # `python -m probvis.cli` starts as the console command does, its checks of the
    from probvis.__main__ import main as _start  # environment made before the libraries load (they would crash)
    sys.exit(_start())

import argparse
import dataclasses
import json
import os
import re
import shlex
import signal
import threading
import warnings
from pathlib import Path

from . import __version__
from .errors import ProbvisError
from .interrupts import check_stop, reset_stop, stop_now, stop_signals
from .io.image import MAX_EXPOSURE
from .settings import MAX_SEED, parse_float, parse_int
from .visibility.base import Switch
from .visibility.probabilistic.estimator import MAX_POWER


def _defines(items):
    out = {}
    for item in items or []:
        if "=" not in item:
            raise ProbvisError(f"-D expects name=value, got '{item}'")
        k, v = item.split("=", 1)
        if not k.strip():
            raise ProbvisError(f"-D expects name=value, got '{item}' (the name is empty)")
        if k.strip() in out and out[k.strip()] != v.strip():
            raise ProbvisError(f"-D {k.strip()} given twice ({out[k.strip()]}, {v.strip()}): give it once")
        out[k.strip()] = v.strip()
    return out


def _int_at_least(lowest, highest=MAX_SEED):
    """argparse type: a whole number from `lowest` to `highest`."""

    def parse(text):
        try:
            v = parse_int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got '{text}'") from None
        if v < lowest:
            raise argparse.ArgumentTypeError(f"must be at least {lowest}, got {v}")
        if v > highest:
            raise argparse.ArgumentTypeError(f"must be at most {highest}, got {v}")
        return v

    return parse


def _positive_float(text):
    try:
        v = parse_float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got '{text}'") from None
    if not v > 0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return v


def _exposure(text):
    """argparse type: a finite exposure in stops within ±MAX_EXPOSURE."""
    try:
        v = parse_float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of stops, got '{text}'") from None
    if not -MAX_EXPOSURE <= v <= MAX_EXPOSURE:  # NaN fails too
        raise argparse.ArgumentTypeError(f"must be a number of stops from -{MAX_EXPOSURE:g} to {MAX_EXPOSURE:g}, "
                                         f"got {text}")
    return v


def _comma_list(text, convert, what):
    """The comma-separated values of `text` converted, or an argparse error naming `what` was expected."""
    try:
        return tuple(convert(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got '{text}'") from None


def _triple(text):
    v = _comma_list(text, parse_float, "three comma-separated numbers")
    if len(v) != 3:
        raise argparse.ArgumentTypeError(f"expected three comma-separated numbers, got '{text}'")
    return v


def _seed_list(text):
    """argparse type: distinct comma-separated whole numbers >= 0."""
    v = _comma_list(text, parse_int, "comma-separated whole numbers")
    if min(v) < 0 or max(v) > MAX_SEED or len(set(v)) != len(v):
        raise argparse.ArgumentTypeError(f"expected distinct seeds from 0 to {MAX_SEED}, got '{text}'")
    return v


_positive = _int_at_least(1)
MAX_WORKERS = 4 * (os.cpu_count() or 1)  # each worker is a process with its own kernels and scene
_non_negative = _int_at_least(0)


class _Once(argparse.Action):
    """A flag naming one output file: given twice, it is refused (only the last would be written)."""

    def __call__(self, parser, namespace, values, option_string=None):
        if getattr(namespace, self.dest) is not None:
            raise ProbvisError(f"{option_string} given twice ({getattr(namespace, self.dest)}, {values}): it writes "
                               "one file; give it once")
        setattr(namespace, self.dest, values)


class _Setting(argparse.Action):
    """A flag setting one value: given twice with different values it is refused (argparse keeps the last)."""

    def __call__(self, parser, namespace, values, option_string=None):
        given = namespace.__dict__.setdefault("_given", {})
        if self.dest in given and given[self.dest] != values:
            raise ProbvisError(f"{option_string} given twice ({given[self.dest]}, {values}): give it once")
        given[self.dest] = values
        setattr(namespace, self.dest, values)


class _Parser(argparse.ArgumentParser):
    """argparse with the project's one-line error format, and flags spelt out: the checks before parsing (which
    estimator `--visibility` names, a flag given twice) read the whole names, so `--vis` would slip past them."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, allow_abbrev=False, **kwargs)

    def _print_message(self, message, file=None):
        """--help and --version on the standard output as every command prints there: a failing one is said
        (argparse passes over the write's OSError)."""
        if message and (file or sys.stderr) is sys.stdout:
            _stdout_call(sys.stdout.write, message)
        else:
            super()._print_message(message, file)

    def error(self, message):
        if message.startswith("unrecognized arguments:") and not message.split(":", 1)[1].strip():
            message = "unrecognized argument '' (an empty string: check the command's quoting)"
        switch = self._switch_given_a_value(message)
        if switch:
            flag, negated = switch
            raise ProbvisError(f"{message} ({flag} is a switch: give {flag} or --no-{flag[2:]}, without a value)"
                               if negated else f"{message} ({flag} is a switch: give {flag} alone, without a "
                               "value, or leave it out)")
        if message.startswith("unrecognized arguments: ") and "--" in message:
            given = [a for a in message.split(": ", 1)[1].split() if a.startswith("--")]
            flags, owners = [f for a in self._actions for f in a.option_strings], {}
            for sub in self._subparsers._group_actions if self._subparsers else ():
                for name, p in sub.choices.items():
                    for f in (f for a in p._actions for f in a.option_strings):
                        flags.append(f)
                        owners.setdefault(f, []).append(name)
            flag = given[0].split("=")[0] if given else None
            near = [f for f in dict.fromkeys(flags) if flag and f.startswith(flag)]
            argv = getattr(self, "argv", [])
            if flag in flags and "--" in argv:  # a whole flag it did not take: it came after '--'
                message += " (after '--' every argument is a positional one: put the options before '--')"
            elif flag in flags and argv and argv[0] in self._subparsers._group_actions[0].choices:
                others = " and ".join(f"'probvis {o}'" for o in dict.fromkeys(owners.get(flag, [])))
                message += f" ({flag} is an option of {others}, not of 'probvis {argv[0]}')"
            elif near:
                message += f" (flags are spelt out in full: did you mean {' or '.join(near[:3])}?)"
        raise ProbvisError(message)

    def _switch_given_a_value(self, message):
        """(flag, whether it has a --no- form) of the switch given a value: `--strict=yes` (argparse ignores the
        value) or an unrecognised true/false (yes/no, on/off, 1/0) after it in the command; None if none was."""
        parsers = [self, *(p for sub in (self._subparsers._group_actions if self._subparsers else ())
                           for p in sub.choices.values())]
        switches = {f: isinstance(a, argparse.BooleanOptionalAction) for p in parsers for a in p._actions
                    if a.nargs == 0 and not isinstance(a, (argparse._HelpAction, argparse._VersionAction))
                    for f in a.option_strings}
        named = re.match(r"argument (\S+): ignored explicit argument ", message)
        if named:
            flag = max((f for f in named.group(1).split("/") if not f.startswith("--no-")), key=len)
            return (flag, switches.get(flag, False)) if flag in switches else None
        if not message.startswith("unrecognized arguments: "):
            return None
        words = {"true", "false", "yes", "no", "on", "off", "1", "0"}
        argv = getattr(self, "argv", [])
        for before, word in zip(argv, argv[1:]):
            if before in switches and word.lower() in words and word in message.split(": ", 1)[1].split():
                return before, switches[before]
        return None


def _add_option(group, opt):
    """The command-line flag of an estimator's `Option`."""
    help_text = (opt.help + ("" if opt.default is None else f" (default {_show(opt.default)})")).replace("%", "%%")
    if opt.type is bool:
        group.add_argument(opt.flag, dest=opt.name, action=argparse.BooleanOptionalAction, default=None,
                           help=help_text)
    elif opt.type is Switch:  # --shells (on), --shells auto|on|off, --no-shells (off)
        group.add_argument(opt.flag, dest=opt.name, nargs="?", const="on", type=_option_type(opt),
                           metavar="|".join(Switch.CHOICES), help=help_text)
        group.add_argument("--no-" + opt.flag[2:], dest=opt.name, action="store_const", const="off",
                           help=f"{opt.flag} off")
    else:
        group.add_argument(opt.flag, dest=opt.name, type=_option_type(opt), metavar=opt.metavar or
                           (None if opt.choices else opt.name.upper()), choices=None, help=help_text)


def _show(value):
    return ",".join(f"{x:g}" for x in value) if isinstance(value, tuple) else str(value).lower() \
        if isinstance(value, bool) else str(value)


def _option_type(opt):
    def parse(text):
        try:
            return opt.parse(text)
        except ProbvisError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    parse.__name__ = opt.name
    return parse


def _parser(estimator=None):
    """The command-line parser; `render` gets the flags of `estimator` (a class) when given."""
    from .visibility import available_names

    p = _Parser(prog="probvis", description="Direct illumination with measurable visibility.")
    p.add_argument("--version", action="version", version=f"probvis {__version__}")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)

    r = sub.add_parser("render", help="render a scene to EXR/PFM/PNG and report its statistics")
    r.add_argument("scene", help="Mitsuba XML file or built-in scene name (see `probvis scenes`)")
    r.add_argument("-o", "--output", action="append", metavar="OUT",
                   help="output image (.exr, .pfm, .png); repeat for several (default: SCENE.exr)")
    r.add_argument("--spp", type=_positive, action=_Setting,
                   help="camera samples per pixel (wins over -D spp=...)")
    r.add_argument("--shadow-rays", type=_positive, action=_Setting,
                   help="emitter samples (shadow rays) per camera sample (wins over -D shadow_rays=...)")
    r.add_argument("-D", dest="defines", action="append", metavar="NAME=VALUE",
                   help="set a scene parameter (a <default> of an XML scene; res, spp, shadow_rays or seed of a "
                        "built-in one)")
    r.add_argument("--seed", type=_non_negative, action=_Setting,
                   help="random seed (default: the scene's sampler seed)")
    r.add_argument("--strict", action="store_true", help="refuse appearance probvis would approximate (non-diffuse "
                                                         "BSDFs render as their nearest diffuse colour otherwise)")
    r.add_argument("--visibility", default="exact", metavar="NAME",
                   help=f"visibility estimator: {', '.join(available_names())} or module:Class (default exact; "
                        "`probvis estimators` lists each one's options)")
    r.add_argument("--case-image", metavar="OUT", action=_Once,
                   help="write the per-pixel case shares (R penumbra, G lit, B shadowed, grey unknown), one image "
                        "per emitter (for estimators that classify points)")
    if estimator is not None:
        group = r.add_argument_group(f"options of --visibility {estimator.name}")
        for opt in estimator.options:
            _add_option(group, opt)
    r.add_argument("--filter-importance", action="store_true",
                   help="draw camera samples from the film's reconstruction filter, one pixel each, instead of "
                        "splatting each over the pixels the filter covers as Mitsuba does (noisier)")
    r.add_argument("--clamp-negative", action="store_true",
                   help="clamp negative pixels to zero (biased: too bright on average; the bias is reported)")
    r.add_argument("--stats", metavar="OUT.json", action=_Once, help="write the statistics as JSON")
    r.add_argument("--tests-image", metavar="OUT.exr", action=_Once,
                   help="write per-pixel ray-triangle and ray-node test counts")
    r.add_argument("--threads", type=_positive, action=_Setting, help="worker threads (default: all cores)")
    r.add_argument("--exposure", type=_exposure, action=_Setting, default=0.0,
                   help="PNG exposure in stops (default 0)")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no summary")

    i = sub.add_parser("info", help="triangles, emitters, bounds and BVH statistics of a scene")
    i.add_argument("scene")
    i.add_argument("-D", dest="defines", action="append", metavar="NAME=VALUE")
    i.add_argument("--json", action="store_true", help="print JSON")

    sub.add_parser("scenes", help="list the built-in scenes")

    v = sub.add_parser("estimators", help="list the visibility estimators with their options, phases and AOVs")
    v.add_argument("name", nargs="?", help="one estimator (a name or module:Class)")
    v.add_argument("--json", action="store_true", help="print JSON")

    t = sub.add_parser("tables", help="per decomposition: term values and variance in the four configurations")
    t.add_argument("--json", action="store_true", help="print JSON")
    t.add_argument("--probabilities", type=_triple, action=_Setting, metavar="P1,P2,P3",
                   help="term probabilities (default 1/3)")
    t.add_argument("--shifts", type=_triple, action=_Setting, metavar="A,B,G",
                   help="shifts of the shifted decomposition")
    t.add_argument("--power", type=_int_at_least(2, MAX_POWER), action=_Setting, default=8,
                   help=f"exponent of the power decomposition, 2 to {MAX_POWER} (default 8)")

    e = sub.add_parser("experiment", help="run a study (TOML) on Dask and write a browsable report",
                       description="Render every cell (scene x method x shadow rays x seed) of a study, caching "
                                   "each on disk so an interrupted study resumes, and write a report folder.")
    e.add_argument("file", nargs="?", help="experiment TOML file (e.g. experiments/paper.toml)")
    e.add_argument("--quick", action="store_true", help="the built-in quick preset instead of a file")
    e.add_argument("-o", "--output", metavar="DIR", action=_Setting, help="report folder (default: experiment-NAME)")
    e.add_argument("--cache", metavar="DIR", action=_Setting, help="render cache folder (default: DIR/cache)")
    e.add_argument("--seeds", type=_seed_list, action=_Setting, metavar="S1,S2,...",
                   help="render these seeds instead of the file's")
    e.add_argument("--workers", type=_int_at_least(1, MAX_WORKERS), action=_Setting, default=1,
                   help=f"LocalCluster worker processes (default 1, at most {MAX_WORKERS}: four per core)")
    e.add_argument("--scheduler", metavar="ADDRESS", action=_Setting,
                   help="use the Dask scheduler at ADDRESS (tcp://host:port)")
    e.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.render_flags = set(r._option_string_actions)  # `render`'s own flags and the estimator's
    return p


def _plan_outputs(outputs, args):
    """Check every file a render will write before it starts: each writable, of its role's format, and no two
    the same file. Returns them by resolved path (the owner's flag and name)."""
    from .io import check_writable
    from .io.image import FORMATS

    planned = [(p, "-o", FORMATS) for p in outputs]
    planned += [(p, flag, fmts) for p, flag, fmts in ((args.stats, "--stats", (".json",)),
                                                      (args.tests_image, "--tests-image", (".exr",)),
                                                      (args.case_image, "--case-image", FORMATS)) if p is not None]
    seen = {}
    for path, flag, formats in planned:
        check_writable(path, formats, f"{flag}'s output")
        key = Path(path).resolve()
        if key in seen:
            raise ProbvisError(f"{flag} {path}: the same file as {seen[key]}; give each output its own name")
        seen[key] = f"{flag} {path}"
    if args.case_image:  # with several emitters it writes NAME-e0.ext, NAME-e1.ext, ... instead: each of those
        # is checked once the scene's emitters are known (`_plan_case_images`)
        given = Path(args.case_image)
        case = given.resolve()
        per_emitter = re.compile(re.escape(case.stem) + r"-e\d+" + re.escape(case.suffix))
        for key, owner in seen.items():
            if key.parent == case.parent and per_emitter.fullmatch(key.name):
                raise ProbvisError(f"--case-image {args.case_image}: with several emitters it writes {key.name}, the "
                                   f"same file as {owner}; give each output its own name")
        check_writable(given, FORMATS, "--case-image's output")  # as given: a scene with one emitter writes it
    return seen


def _plan_case_images(args, planned, paths):
    """Check the per-emitter case images `paths` as `_plan_outputs` checks outputs, and add them to `planned`."""
    from .io import check_writable
    from .io.image import FORMATS

    for path in paths:
        check_writable(path, FORMATS, "--case-image's output")
        key = Path(path).resolve()
        if key in planned and not planned[key].startswith(f"--case-image {args.case_image}"):
            raise ProbvisError(f"--case-image {args.case_image}: with several emitters it writes {path}, the same "
                               f"file as {planned[key]}; give each output its own name")
        planned[key] = f"--case-image {args.case_image} ({Path(path).name})"


def _refuse_inputs(planned, inputs):
    """An error if a planned output (`_plan_outputs`) is one of the files the scene was read from (a texture or
    an environment map given as `-o`): checked after the render, which reads the scene, before any write."""
    for path in inputs:
        if (owner := planned.get(Path(path).resolve())) is not None:
            raise ProbvisError(f"{owner}: the scene reads this file ({path}); writing it would replace the scene's "
                               "own input: give the output another name")


def _cmd_render(args):
    from .integrator import render
    from .io import staged_writes, summary, write_case_images, write_exr, write_image, write_stats
    from .io.case_images import case_image_paths

    cls = args.estimator_class
    if args.case_image and not any(a.kind == "cases" for a in cls.aovs):
        raise ProbvisError(f"--case-image needs an estimator that classifies points (e.g. occlusion-map), not "
                           f"'{cls.name}'")
    outputs = args.output or [f"{Path(args.scene).stem}.exr"]
    planned = _plan_outputs(outputs, args)
    if args.exposure and not any(Path(o).suffix.lower() == ".png" for o in outputs):
        warnings.warn("--exposure applies to PNG outputs only (EXR and PFM keep the radiance): ignored", stacklevel=1)
    options = {o.name: getattr(args, o.name) for o in cls.options if getattr(args, o.name) is not None}
    folder = os.getcwd()
    try:
        result = render(args.scene, spp=args.spp, shadow_rays=args.shadow_rays, seed=args.seed, threads=args.threads,
                        visibility=cls, visibility_options=options, defines=_defines(args.defines),
                        strict=args.strict, clamp_negative=args.clamp_negative, progress=not args.quiet,
                        filter_importance=args.filter_importance or None)
    finally:  # a plug-in that changed folder: the outputs are named relative to the user's
        os.chdir(folder)
    if args.case_image and "cases" not in result.aovs:
        raise ProbvisError(f"--case-image: '{cls.name}' classified no shading point (its classify returned None)")
    if args.case_image and result.aovs["cases"].shape[2] > 1:
        _plan_case_images(args, planned, case_image_paths(args.case_image, result.aovs["cases"].shape[2]))
    _refuse_inputs(planned, result.stats["inputs"])
    check_stop()  # a stop that a plug-in swallowed: nothing is written
    with staged_writes():  # every output or none
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
        if not args.quiet:  # before the files appear: a standard output that fails leaves none of them
            _say(summary(result.stats))
            _flush_stdout()
    if not args.quiet:
        _say("wrote       " + ", ".join(written))
    return 0


def _render_path_doc(cls):
    """How an estimator class renders: "staged" (segments, `evaluate`), or what its own `render_path` says."""
    from .visibility import VisibilityEstimator

    if cls.render_path is VisibilityEstimator.render_path:
        return "staged"
    doc = " ".join((cls.render_path.__doc__ or "its own choice").split())
    return doc.split(". ")[0].rstrip(".")


def _describe(cls):
    """An estimator's declarations as a JSON-serialisable dict."""
    return {
        "name": cls.name, "class": f"{cls.__module__}:{cls.__qualname__}", "summary": cls.summary,
        "render_path": _render_path_doc(cls),
        "options": [{"name": o.name, "flag": o.flag, "type": o.describe_type(),
                     "default": list(o.default) if isinstance(o.default, tuple) else o.default, "help": o.help}
                    for o in cls.options],
        "phases": [{"name": p.name, "stage": p.stage, "help": p.help} for p in cls.phases],
        "aovs": [{"name": a.name, "kind": a.kind, "help": a.help} for a in cls.aovs],
    }


def _cmd_estimators(args):
    from .visibility import available_names, estimator_class

    if args.name is not None and not args.name.strip():  # an unset shell variable: not "list them all"
        raise ProbvisError("the estimator's name is empty (leave it out to list every estimator)")
    described = []
    for name in [args.name] if args.name else available_names():
        try:
            described.append(_describe(estimator_class(name)))
        except ProbvisError as exc:  # listing all: an installed estimator that does not load is named, not fatal
            if args.name:
                raise
            described.append({"name": name, "error": str(exc)})
    if args.json:
        _say(json.dumps(described, indent=1))
        return 0
    for d in described:
        if "error" in d:
            _say(f"{d['name']}  —  cannot be loaded: {d['error']}\n")
            continue
        _say(f"{d['name']}  —  {d['summary']}")
        _say(f"    class {d['class']}; render path: {d['render_path']}")
        for o in d["options"]:
            default = "automatic" if o["default"] is None else _show(o["default"])
            if o["type"] == "true/false":  # true/false in the API and a study's TOML, a switch on the command line
                _say(f"    {o['flag']} / --no-{o['flag'][2:]}  (a switch; true/false in the API; default {default})")
            else:
                _say(f"    {o['flag']}  ({o['type']}; default {default})")
            _say(f"        {o['help']}")
        if d["phases"]:
            _say("    phases: " + ", ".join(f"{p['name']} ({p['stage']})" for p in d["phases"]))
        if d["aovs"]:
            _say("    AOVs:   " + ", ".join(a["name"] for a in d["aovs"]))
        _say()
    return 0


def _cmd_info(args):
    import numpy as np

    from .accel import build_bvh
    from .emitters import build_emitter_sampler
    from .scene import open_scene

    scene = open_scene(args.scene, _defines(args.defines))
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
        "emitters": [_emitter_info(scene, es, e) for e in range(scene.n_emitters)],
        "camera": {"width": cam.width, "height": cam.height, "fov_x": cam.fov_x,
                   "origin": cam.to_world[:3, 3].tolist()},
        "spp": scene.defaults.spp,
        "shadow_rays_per_sample": scene.defaults.shadow_rays,
        "bvh": bvh.stats(),
    }
    if args.json:
        _say(json.dumps(info, indent=2))
        return 0
    _say(f"scene      {info['scene']} ({info['source']})")
    _say(f"triangles  {info['triangles']:,}" + (f" ({scene.dropped_degenerate} degenerate dropped)"
                                               if scene.dropped_degenerate else ""))
    _say(f"bounds     {np.round(lo, 4).tolist()} .. {np.round(hi, 4).tolist()}")
    _say(f"camera     {cam.width}x{cam.height}, fov_x {cam.fov_x:.4g} deg, {scene.defaults.spp} spp x "
         f"{scene.defaults.shadow_rays} shadow rays")
    for e, em in enumerate(info["emitters"]):
        quantity = next(q for q in _EMITTER_QUANTITY.values() if q in em)
        size = f", {em['map'][0]}x{em['map'][1]} map" if em.get("map") else ""
        area = f", area {em['area']:.4g}" if em["area"] is not None else ""
        _say(f"emitter {e}  {em['kind']}: {quantity} {em[quantity]}{size}{area}, power {em['power']:.4g}, "
             f"p {em['selection_probability']:.3f}")
    b = info["bvh"]
    _say(f"bvh        {b['nodes']:,} nodes, {b['leaves']:,} leaves, depth {b['max_depth']}, "
         f"mean leaf {b['mean_leaf_size']:.2f}, SAH cost {b['sah_cost']:.2f}, built in {b['build_seconds']:.3f} s")
    for s in info["shapes"]:
        _say(f"shape      {s['name']:<16} {s['type']:<10} {s['triangles']:>8,} triangles"
             + ("  (emitter)" if s["emitter"] >= 0 else ""))
    return 0


_EMITTER_QUANTITY = {"area": "radiance", "point": "intensity", "spot": "intensity", "directional": "irradiance",
                     "environment": "scale"}


def _emitter_info(scene, es, e):
    """What `info` says of emitter e: its kind and its own quantity (an area light's radiance, a point or spot
    light's intensity, a directional light's irradiance, an environment's scale and map size), the area only of
    area lights."""
    from .scene.scene import EMITTER_AREA, EMITTER_ENVIRONMENT

    kind = ("area", "point", "spot", "directional", "environment")[int(scene.emitter_kind[e])]
    out = {"kind": kind, _EMITTER_QUANTITY[kind]: scene.emitter_radiance[e].tolist(),
           "area": float(es.emitter_area[e]) if scene.emitter_kind[e] == EMITTER_AREA else None}
    env = scene.environment
    if scene.emitter_kind[e] == EMITTER_ENVIRONMENT and env is not None:
        out["map"] = None if env.constant else [int(env.image.shape[1]), int(env.image.shape[0])]
    out.update(power=float(es.power[e]), selection_probability=float(es.emitter_pmf[e]))
    return out


def _cmd_scenes(args):
    from .scene import BUILTINS

    for name, (_, text) in BUILTINS.items():
        _say(f"{name:<14} {text}")
    return 0


def _cmd_tables(args):
    from .visibility.probabilistic import power, shifted, standard

    p = args.probabilities or (1 / 3, 1 / 3, 1 / 3)
    decs = []
    for flag, make in (("--probabilities", lambda: standard(p)),
                       ("--shifts", lambda: shifted(p, args.shifts or (1 / 3, 1 / 3, 1 / 3))),
                       ("--power", lambda: power(args.power, p))):
        try:
            decs.append(make())
        except ValueError as exc:
            raise ProbvisError(f"{flag}: {exc}") from None
    out = [{"decomposition": d.name, "probabilities": d.p.tolist(), "terms": list(d.labels), "rows": d.rows()}
           for d in decs]
    if args.json:
        _say(json.dumps(out, indent=1))
        return 0
    for d in out:
        _say(f"{d['decomposition']}  (p = {', '.join(f'{x:.4g}' for x in d['probabilities'])})")
        _say(f"  {'V_A':>3} {'V_B':>3} {'V_A V_B':>7}  " + "".join(f"{t:>24}" for t in d["terms"])
             + f"{'variance':>12}")
        for r in d["rows"]:
            _say(f"  {r['VA']:>3} {r['VB']:>3} {r['product']:>7}  " + "".join(f"{v:>24.6g}" for v in r["values"])
                 + f"{r['variance']:>12.6g}")
        _say()
    return 0


def _cmd_experiment(args):
    from .experiments import experiment, load_experiment, quick_experiment

    if args.quick and args.file:
        raise ProbvisError("give an experiment file or --quick, not both")
    if not (args.quick or args.file):
        raise ProbvisError("give an experiment file (e.g. experiments/paper.toml) or --quick")
    if args.scheduler is not None and not args.scheduler.strip():
        raise ProbvisError("--scheduler needs a Dask scheduler's address (tcp://host:port); it is empty (leave the "
                           "option out for a local cluster)")
    if args.scheduler and args.workers != 1:
        raise ProbvisError("--workers applies to the embedded LocalCluster, not to --scheduler")
    if args.scheduler and args.scheduler.startswith("inproc://"):
        raise ProbvisError(f"--scheduler '{args.scheduler}': an inproc:// address names a scheduler inside one "
                           "process, which the command line cannot reach; give tcp://host:port")
    if args.scheduler and not re.fullmatch(r"(?:(?:tcp|tls|ws|wss|ucx)://)?[\w.\-\[\]]+(?::\d{1,5})?/?",
                                           args.scheduler):
        raise ProbvisError(f"--scheduler '{args.scheduler}' is not a scheduler address (tcp://host:port)")
    for flag, value in (("-o", args.output), ("--cache", args.cache)):
        if value is not None and not value.strip():
            raise ProbvisError(f"{flag} needs a folder name (got an empty one)")
    if args.cache is not None and Path(args.cache).exists() and not Path(args.cache).is_dir():
        raise ProbvisError(f"--cache '{args.cache}' is a file, not a folder: give a folder for the renders' cache")
    exp = quick_experiment() if args.quick else load_experiment(args.file)
    if args.seeds:
        exp = dataclasses.replace(exp, seeds=args.seeds)
    out = Path(args.output or f"experiment-{exp.name}")
    command = "probvis " + shlex.join(args.argv)
    try:  # `main` made SIGTERM and SIGHUP stop as Ctrl-C does
        _, index, run = experiment(exp, out, args.cache, args.workers, args.scheduler, not args.quiet, command)
    except KeyboardInterrupt:
        cache = Path(args.cache or out / "cache")
        kept = cache.is_dir() and any(cache.glob("*.json"))
        print(f"probvis: interrupted; finished renders are kept in {cache}, run the same command to resume" if kept
              else "probvis: interrupted before any render finished", file=sys.stderr)
        return 130
    try:
        check_stop()  # a stop that a library swallowed (while the cluster started, or the report was written)
    except KeyboardInterrupt:  # the study ran to its end all the same: nothing to resume
        print(f"probvis: interrupted as the study finished; its report is complete: {index}", file=sys.stderr)
        return 130
    _say(f"{run.computed} renders computed, {run.cells_cached} of {len(run.tasks)} cells from the cache; "
         f"report: {index}")
    return 0


def _warning_line(message, category, filename, lineno, file=None, line=None):
    """A warning as one line: a library's multi-line, coloured text (Numba's) keeps its first line, uncoloured."""
    text = str(message).strip().splitlines()
    print(f"probvis: warning: {_one_line(text[0]) if text else category.__name__}", file=sys.stderr)


_COLOURS = re.compile(r"\x1b\[[0-9;]*m")  # terminal colours, as Numba's errors and warnings carry them


MAX_MESSAGE = 2000  # characters of a message shown whole; a longer one (a huge value quoted) keeps both ends


def _one_line(text):
    """`text` without terminal colours and with its other control characters escaped (a newline in a file name,
    a terminal escape in a file's line): a message stays one line and cannot drive the terminal. A message longer
    than MAX_MESSAGE keeps its start and end (what was wrong, and what to do) around an elision."""
    text = _COLOURS.sub("", str(text))
    if len(text) > MAX_MESSAGE:
        head, tail = text[:MAX_MESSAGE * 2 // 3], text[-MAX_MESSAGE // 3:]
        text = f"{head} [... {len(text) - MAX_MESSAGE:,} characters ...] {tail}"
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def _visibility_arg(argv):
    """The value of render's --visibility in `argv`, if any (read before parsing: it decides the flags)."""
    given = []
    for i, a in enumerate(argv):
        if a == "--visibility" and i + 1 < len(argv):
            given.append(argv[i + 1])
        elif a.startswith("--visibility="):
            given.append(a.split("=", 1)[1])
    if len(given) > 1:
        raise ProbvisError(f"--visibility given {len(given)} times ({', '.join(given)}): give one estimator")
    return given[0] if given else "exact"


def _caused_by_interrupt(exc):
    """Whether a KeyboardInterrupt is among the causes of `exc` (a SystemError per compiled frame it crossed)."""
    while exc is not None:
        if isinstance(exc, KeyboardInterrupt):
            return True
        exc = exc.__cause__ or exc.__context__
    return False


def _unraisable(unraisable):
    """An interrupt inside a library's callback (llvmlite's, while Numba compiles) is reported once, as the
    interrupt; anything else as Python would."""
    if not issubclass(unraisable.exc_type, KeyboardInterrupt):
        sys.__unraisablehook__(unraisable)


class _StdoutFailed(Exception):
    """Writing the standard output failed (its OSError's reason)."""


def _say(*args):
    """Print to the standard output; a closed or failing one (`>&-`, `> /dev/full`) is `_StdoutFailed`."""
    if sys.stdout is None:
        raise _StdoutFailed("it is closed")
    _stdout_call(print, *args)


def _flush_stdout():
    """Flush what a command printed, so that a failing standard output is reported here, not at exit."""
    if sys.stdout is not None:
        _stdout_call(sys.stdout.flush)


def _stdout_call(write, *args):
    """`write(*args)` on the standard output, its failure (other than the reader leaving) `_StdoutFailed`."""
    try:
        write(*args)
    except BrokenPipeError:
        raise
    except (OSError, ValueError) as exc:
        raise _StdoutFailed(getattr(exc, "strerror", None) or exc) from None


def _drop_stdout():
    """Point the standard output at /dev/null, so the interpreter's own flush at exit finds nothing to fail."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (AttributeError, OSError, ValueError):
        pass


def _foreign_flags(argv, cls, known):
    """Estimator flags in `argv` that `cls` does not declare: (flag, names of the estimators that do). `known`
    are `render`'s flags with `cls`'s: only an unknown flag makes the other estimators load."""
    from .visibility import available_names, estimator_class

    own = {o.flag for o in cls.options} | {"--no-" + o.flag[2:] for o in cls.options if o.type in (bool, Switch)}
    if all(a.split("=", 1)[0] in known for a in argv if a.startswith("--")):
        return None
    owners = {}
    for name in available_names():
        try:
            other = estimator_class(name)
        except ProbvisError:  # an installed estimator that does not load: `probvis estimators` names it
            continue
        for o in other.options:
            for flag in (o.flag, "--no-" + o.flag[2:]):
                owners.setdefault(flag, []).append(name)
    for a in argv:
        flag = a.split("=", 1)[0]
        if flag in owners and flag not in own:
            return flag, owners[flag]
    return None


def _repeated_option(argv, cls):
    """The flags of an estimator option given more than once in `argv` (`--shells on --no-shells`), or None."""
    for o in cls.options:
        flags = {o.flag, "--no-" + o.flag[2:]} if o.type in (bool, Switch) else {o.flag}
        given = [a for a in argv if a.split("=", 1)[0] in flags]
        if len(given) > 1:
            return given
    return None


_NEGATIVE = re.compile(r"-(?:[0-9.]+(?:e[+-]?[0-9]+)?|inf|infinity|nan)(?:,\S*)?", re.IGNORECASE)


def _negative_values(argv):
    """`--exposure -inf` as `--exposure=-inf`, `--shifts -1,1,1` as `--shifts=-1,1,1`: argparse takes a value
    starting with '-' that is not a plain number for a flag, and would say only "expected one argument"."""
    out = list(argv)
    for i in range(len(out) - 1):
        if out[i] and out[i].startswith("--") and "=" not in out[i] and _NEGATIVE.fullmatch(out[i + 1] or ""):
            out[i:i + 2] = [f"{out[i]}={out[i + 1]}", None]
    return [a for a in out if a is not None]


def _parse(argv):
    """Parse `argv`; for `render`, with the flags of the estimator its --visibility names."""
    argv = _negative_values(argv)
    cls = None
    if argv and argv[0] == "render":
        from .visibility import estimator_class

        cls = estimator_class(_visibility_arg(argv), what="--visibility")
    parser = _parser(cls)
    if cls is not None:
        foreign = _foreign_flags(argv, cls, parser.render_flags)
        if foreign:
            flag, owners = foreign
            raise ProbvisError(f"{flag} does not apply to --visibility {cls.name} (it is an option of "
                               f"{', '.join(owners)}; see `probvis estimators`)")
        repeated = _repeated_option(argv, cls)
        if repeated:
            raise ProbvisError(f"{' and '.join(repeated)} set the same option: give it once")
    parser.argv = argv  # for its error lines: whether the command has a '--'
    args = parser.parse_args(argv)
    args.estimator_class = cls
    return args


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    warnings.showwarning = _warning_line
    # the command's warnings are lines on stderr, whatever PYTHONWARNINGS or -W say (error made them tracebacks)
    warnings.filterwarnings("default", category=UserWarning)
    sys.unraisablehook = _unraisable
    # Numba guards its first parallel launch with a multiprocessing lock; without one (no /dev/shm, a file size
    # limit) it warns at length, though a render runs one process
    warnings.filterwarnings("ignore", message=".*Could not obtain multiprocessing lock")
    if os.environ.get("NUMBA_DISABLE_JIT", "0").strip() not in ("", "0"):  # kernels run as Python, on NumPy
        warnings.filterwarnings("ignore", message="overflow encountered in scalar")  # scalars: the hashes wrap
    main_thread = threading.current_thread() is threading.main_thread()
    reset_stop()
    previous = {s: signal.signal(s, stop_now) for s in stop_signals()} if main_thread else {}
    if hasattr(sys.stdout, "reconfigure"):  # a scene's non-ASCII name under an ASCII locale: escaped, not a crash
        sys.stdout.reconfigure(errors="backslashreplace")
    command = None
    try:
        try:
            os.getcwd()
        except FileNotFoundError:
            raise ProbvisError("the current folder no longer exists (it was deleted): cd to an existing folder") \
                from None
        try:
            args = _parse(argv)
        except SystemExit as done:  # --help or --version printed: a failing standard output is said, not lost
            if done.code == 0:
                _flush_stdout()
            raise
        args.argv = argv
        command = args.command
        status = {"render": _cmd_render, "info": _cmd_info, "scenes": _cmd_scenes, "estimators": _cmd_estimators,
                  "tables": _cmd_tables, "experiment": _cmd_experiment}[args.command](args)
        _flush_stdout()
        return status
    except ProbvisError as exc:
        print(f"probvis: error: {_one_line(exc)}", file=sys.stderr)
        return 2
    except MemoryError:  # an allocation the estimate before the render did not foresee (a texture's, say)
        advice = {"render": ": lower the resolution, --spp, --shadow-rays or the scene's texture sizes",
                  "info": ": lower the scene's texture and environment map sizes",
                  "experiment": ": lower the study's resolution, spp or shadow rays, or its scenes' texture sizes"}
        print("probvis: error: out of memory (the machine's or the process's limit, ulimit -v)"
              f"{advice.get(command, '')}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("probvis: interrupted, nothing written", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `probvis tables | head`: the reader left; say nothing more
        _drop_stdout()
        return 141
    except _StdoutFailed as exc:  # stdout on a full disk (`> /dev/full`) or closed
        _drop_stdout()
        print(f"probvis: error: cannot write to the standard output: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # a file the checks did not foresee (a name too long for the file system, say)
        if exc.filename is None:
            raise
        print(f"probvis: error: {_one_line(exc.filename)}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except UnicodeEncodeError as exc:  # a name in a scene or study file under a locale that cannot encode it
        if exc.encoding != sys.getfilesystemencoding():
            raise
        name = exc.object if isinstance(exc.object, str) else repr(exc.object)
        print(f"probvis: error: '{_one_line(name)}': the file system's encoding here ({exc.encoding}, from the "
              "locale) cannot represent this name: run with a UTF-8 locale (LANG=C.UTF-8) or PYTHONUTF8=1",
              file=sys.stderr)
        return 2
    except Exception as exc:  # Ctrl-C or SIGTERM while compiled code returned (a SystemError chains it as a
        # cause) or inside Numba's compiler, where a callback swallows it and the compile fails on its own terms
        from .interrupts import interrupt_received

        if not (_caused_by_interrupt(exc) or interrupt_received()):
            raise
        print("probvis: interrupted, nothing written", file=sys.stderr)
        return 130
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)

