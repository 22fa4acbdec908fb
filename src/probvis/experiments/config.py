"""Experiment definitions: a TOML file of scenes x methods x shadow-ray counts x seeds, validated up front.

Every key is checked against the schema below, so a typo is an error naming the key, never a silent default.
Paths inside the file are relative to the file.
"""
import dataclasses
import hashlib
import math
import os
import re
import tomllib
import unicodedata
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from ..errors import ProbvisError, checked_call, is_path, missing_file, shown
from ..scene import BUILTINS
from ..settings import MAX_SEED, MAX_SEGMENTS_PER_PIXEL, MAX_SHADOW_RAYS, MAX_SPP
from ..visibility import estimator_class

MAX_RESOLUTION = 1 << 15

TOP_KEYS = {"name", "description", "spp", "shadow_rays", "seeds", "resolution", "target_relmse", "table_shadow_rays",
            "timing_repeats", "timing_seconds", "seconds",
            "reference", "scenes", "methods"}
REFERENCE_KEYS = {"spp", "shadow_rays", "seed", "visibility"}
STUDY_SETTINGS = {"spp": "spp", "shadow_rays": "shadow_rays", "seed": "seeds"}  # defines the study's settings win over
SCENE_KEYS = {"name", "source", "defines", "reference", "reference_noise"}
METHOD_KEYS = {"name", "visibility", "options", "baseline"}


MADE_BY = "an Experiment (load_experiment or parse_experiment makes one)"


@dataclass(frozen=True)
class SceneSpec:
    """A scene of the study: `source` is a built-in name or an XML path; `reference` an optional image file."""

    name: str
    source: str
    defines: dict = field(default_factory=dict)
    reference: str | None = None
    reference_noise: float = 0.0  # the reference file's own per-pixel relMSE (for the bias column)


@dataclass(frozen=True)
class MethodSpec:
    """A visibility estimator with its options, under a short label."""

    name: str
    visibility: str
    options: dict = field(default_factory=dict)


@dataclass(frozen=True)
class ReferenceSettings:
    spp: int = 64
    shadow_rays: int = 64
    seed: int = 1_000_003
    visibility: str = "exact"


@dataclass(frozen=True)
class Timing:
    """How a cell's seconds are measured: up to `repeats` renders, fewer once they took `enough_seconds`
    together; the fastest counts (the image is the same each time)."""
    repeats: int = 1
    enough_seconds: float = math.inf


@dataclass(frozen=True)
class Experiment:
    name: str
    description: str
    scenes: tuple
    methods: tuple
    shadow_rays: tuple
    spp: int
    seeds: tuple
    reference: ReferenceSettings
    baseline: str
    table_shadow_rays: int
    resolution: tuple | None = None
    target_relmse: float | None = None
    timing_repeats: int = 1  # renders of each cell; its seconds are the fastest (the image is the same)
    timing_seconds: float = math.inf  # a cell stops repeating once its renders took this long together
    seconds: str = "total"  # what a cell's seconds count: "total" (without JIT compile) or "render" (also
    # without scene loading and the scene BVH, which every method shares: the render and the estimator's
    # preparation)

    @property
    def timing(self):
        return Timing(self.timing_repeats, self.timing_seconds)


def _fail(where, message):
    raise ProbvisError(f"{where}: {message}")


def _table(where, value):
    if not isinstance(value, dict):
        _fail(where, f"expected a table, got {value!r}")
    return value


def _check_keys(where, table, allowed):
    unknown = sorted(set(_table(where, table)) - allowed)
    if unknown:
        _fail(where, f"unknown key{'s' if len(unknown) > 1 else ''} {', '.join(map(repr, unknown))} "
                     f"(allowed: {', '.join(sorted(allowed))})")


def _int(where, value, lowest=1, highest=MAX_SEED):
    if isinstance(value, bool) or not isinstance(value, int) or value < lowest:
        _fail(where, f"expected a whole number >= {lowest}, got {value!r}")
    if value > highest:
        _fail(where, f"expected a whole number <= {highest}, got {value!r}")
    return value


def _seconds(where, value):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
        _fail(where, f"expected a number of seconds > 0, got {value!r}")
    return float(value)


def _int_list(where, value, lowest=1, distinct=True, highest=MAX_SEED):
    if not isinstance(value, list) or not value:
        _fail(where, f"expected a non-empty list of whole numbers, got {value!r}")
    items = [_int(f"{where}[{i}]", v, lowest, highest) for i, v in enumerate(value)]
    if distinct and len(set(items)) != len(items):
        _fail(where, f"repeated values in {value!r}")
    return tuple(items)


_BIDI_CONTROLS = {"LRE", "RLE", "LRO", "RLO", "PDF", "LRI", "RLI", "FSI", "PDI"}  # they reorder the report's text


def _str(where, value):
    if not isinstance(value, str) or not value.strip():
        _fail(where, f"expected a non-empty string, got {value!r}")
    if any(unicodedata.category(c) == "Cc" or unicodedata.bidirectional(c) in _BIDI_CONTROLS for c in value):
        _fail(where, f"control characters (tabs, newlines, text-direction overrides) have no place in a name or "
                     f"path here, got {value!r}")
    return value


def _scene(where, table, base):
    _check_keys(where, table, SCENE_KEYS)
    for key in ("name", "source"):
        if key not in table:
            _fail(where, f"missing key '{key}'")
    name, source = _str(f"{where}.name", table["name"]), _str(f"{where}.source", table["source"])
    if source not in BUILTINS:
        source = os.path.expanduser(source)  # ~ as a shell (and PROBVIS_CACHE_DIR) reads it
        path = Path(os.path.realpath(base / source))
        if not path.is_file():
            if os.path.lexists(base / source):  # a folder, a FIFO, a broken or looping link
                _fail(f"{where}.source", missing_file(base / source, "scene file"))
            _fail(f"{where}.source", f"'{source}' is neither a built-in scene ({', '.join(BUILTINS)}) nor a file "
                                     f"(looked for {path})")
        source = str(path)
    defines = _table(f"{where}.defines", table.get("defines", {}))
    for key, value in defines.items():
        if not isinstance(key, str) or not key.strip():
            _fail(f"{where}.defines", f"parameter names must be non-empty strings, got {key!r}")
        if not isinstance(value, (str, int, float)):  # a bool is an int; a TOML date or an object is neither
            _fail(f"{where}.defines.{key}", f"expected a number, string or boolean, got {shown(value, repr)}")
        if key in STUDY_SETTINGS:  # each cell's own, as --spp wins over -D spp: the define would change nothing
            _fail(f"{where}.defines.{key}", f"the study sets every cell's {key} ({STUDY_SETTINGS[key]} at the top "
                                            "of the file, and reference.* for the reference): a scene's define of "
                                            "it would change nothing")
    reference = table.get("reference")
    if reference is not None:
        given = base / os.path.expanduser(_str(f"{where}.reference", reference))
        ref = Path(os.path.realpath(given))
        if not ref.is_file():
            _fail(f"{where}.reference", f"{ref} is not a regular file" if ref.exists() else missing_file(given, "image"))
        if ref.suffix.lower() not in (".exr", ".pfm"):
            _fail(f"{where}.reference", f"{ref.name} is not an EXR or PFM image (a reference holds linear "
                                        "radiance, as probvis and Mitsuba write it: .exr or .pfm)")
        reference = str(ref)
    noise = table.get("reference_noise", 0.0)
    if isinstance(noise, bool) or not isinstance(noise, (int, float)) or not 0 <= noise < float("inf"):
        _fail(f"{where}.reference_noise", f"expected a number >= 0, got {noise!r}")
    if "reference_noise" in table and reference is None:
        _fail(f"{where}.reference_noise", "applies to a reference file only (a rendered one measures its own)")
    defines = {k: str(v).lower() if isinstance(v, bool) else str(v) for k, v in defines.items()}  # TOML's true: "true"
    return SceneSpec(name, source, defines, reference, float(noise))


def _visibility(vis, base):
    """An estimator name as the workers will load it: a `file.py:Class` made absolute against `base`."""
    module, _, cls = vis.rpartition(":")
    if module.endswith(".py"):
        return f"{os.path.realpath(base / os.path.expanduser(module))}:{cls}"
    return vis


def _method(where, table, base):
    _check_keys(where, table, METHOD_KEYS)
    for key in ("name", "visibility"):
        if key not in table:
            _fail(where, f"missing key '{key}'")
    name = _str(f"{where}.name", table["name"])
    vis = _visibility(_str(f"{where}.visibility", table["visibility"]), base)
    options = {k: tuple(v) if isinstance(v, list) else v
               for k, v in _table(f"{where}.options", table.get("options", {})).items()}
    if not all(isinstance(k, str) for k in options):
        _fail(f"{where}.options", f"option names must be strings, got {sorted(map(repr, options))}")
    if not isinstance(table.get("baseline", False), bool):
        _fail(f"{where}.baseline", f"expected true or false, got {table['baseline']!r}")
    try:
        cls = estimator_class(vis)
    except ProbvisError as exc:
        _fail(f"method '{name}'", str(exc))
    try:
        cls(**options)  # the estimator's own checks too, not only each option's
    except ProbvisError as exc:
        _fail(f"method '{name}'", str(exc))
    except Exception as exc:  # a plug-in's bug: named as `render` names it
        _fail(f"method '{name}'", f"visibility '{vis}' ({cls.__module__}.{cls.__qualname__}) raised "
                                  f"{type(exc).__name__} in __init__: {shown(exc)}")
    return MethodSpec(name, vis, options)


def _as_toml(value, depth=0):
    """A document built in Python as TOML would give it: tuples and NumPy arrays as lists, NumPy scalars and 0-d
    arrays as Python's numbers, paths as strings."""
    if depth > MAX_DEPTH:
        raise ProbvisError(f"the experiment nests lists or dicts more than {MAX_DEPTH} deep (does one contain "
                           "itself?)")
    if isinstance(value, dict):
        return {k: _as_toml(v, depth + 1) for k, v in value.items()}
    if isinstance(value, np.ndarray) and value.ndim == 0:  # a 0-d array: its one value, as a NumPy scalar is
        return _as_toml(value[()], depth + 1)
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_as_toml(v, depth + 1) for v in value]
    if isinstance(value, (np.bool_, np.integer, np.floating)) and not isinstance(value, np.timedelta64):
        return bool(value) if isinstance(value, np.bool_) else value.item() if isinstance(value, np.integer) \
            else float(value)  # a long double's item() is itself, which TOML's numbers are not
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, os.PathLike):  # a source, reference or plug-in file given as a Path
        return os.fspath(value)
    return value


@checked_call
def parse_experiment(data, base=Path("."), source=""):
    """Validate a parsed TOML document (or one built in Python) into an `Experiment`; `base` resolves relative
    paths."""
    where = source or "experiment"
    if not is_path(base):
        raise ProbvisError(f"base must be the folder relative paths start from (a path), got {type(base).__name__}")
    base = os.fspath(base)
    if not isinstance(data, dict):
        raise ProbvisError(f"an experiment is a table (dict) of its keys, got {type(data).__name__}")
    data = _as_toml(data)
    base = Path(base)
    _check_keys(where, data, TOP_KEYS)
    scenes = data.get("scenes")
    methods = data.get("methods")
    if not isinstance(scenes, list) or not scenes:
        _fail(where, "needs at least one [[scenes]] entry")
    if not isinstance(methods, list) or not methods:
        _fail(where, "needs at least one [[methods]] entry")
    scene_specs = tuple(_scene(f"scenes[{i}]", s, base) for i, s in enumerate(scenes))
    method_specs = tuple(_method(f"methods[{i}]", m, base) for i, m in enumerate(methods))
    for kind, specs in (("scene", scene_specs), ("method", method_specs)):
        names = [s.name for s in specs]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            _fail(where, f"repeated {kind} name{'s' if len(dup) > 1 else ''} {', '.join(map(repr, dup))}")
        stems = {}
        for n in names:  # a file system that ignores case (macOS's, Windows') holds 'City' and 'city' as one
            if (other := stems.setdefault(file_stem(n).casefold(), n)) != n:
                _fail(where, f"{kind} names {other!r} and {n!r} give the same file name {file_stem(n)!r} in the "
                             "report: rename one")
    baselines = [m["name"] for m in methods if m.get("baseline", False)]
    if len(baselines) > 1:
        _fail(where, f"only one method can be the baseline, got {', '.join(baselines)}")
    ref = data.get("reference", {})
    _check_keys(f"{where}.reference", ref, REFERENCE_KEYS)
    reference = ReferenceSettings(
        spp=_int("reference.spp", ref.get("spp", ReferenceSettings.spp), 1, MAX_SPP),
        shadow_rays=_int("reference.shadow_rays", ref.get("shadow_rays", ReferenceSettings.shadow_rays), 1,
                         MAX_SHADOW_RAYS),
        seed=_int("reference.seed", ref.get("seed", ReferenceSettings.seed), 0),
        visibility=_visibility(_str("reference.visibility", ref.get("visibility", "exact")), base))
    try:
        reference_estimator = estimator_class(reference.visibility)()
    except ProbvisError as exc:
        _fail("reference.visibility", str(exc))
    if not reference_estimator.unbiased:
        _fail("reference.visibility", f"'{reference.visibility}' is biased (it converges only as its samples grow "
                                      "without bound): a reference must expect the true image; use exact")
    resolution = data.get("resolution")
    if resolution is not None:
        resolution = _int_list("resolution", resolution, distinct=False, highest=MAX_RESOLUTION)
        if len(resolution) == 1:
            resolution = resolution * 2
        if len(resolution) != 2:
            _fail("resolution", "expected [width, height]")
        for i, spec in enumerate(scene_specs):  # as for spp: the study's setting wins, the define would do nothing
            if "res" in spec.defines:
                _fail(f"scenes[{i}].defines.res", "the study sets every cell's film size (resolution at the top of "
                                                  "the file): a scene's define of res would change nothing")
    shadow_rays = _int_list("shadow_rays", data.get("shadow_rays", [1, 4, 16, 64, 256]), highest=MAX_SHADOW_RAYS)
    target = data.get("target_relmse")
    if target is not None and (isinstance(target, bool) or not isinstance(target, (int, float))
                               or not 0 < target <= MAX_TARGET):
        _fail("target_relmse", f"expected a positive number up to {MAX_TARGET:g}, got {target!r}")
    if not isinstance(data.get("description", ""), str):
        _fail("description", f"expected a string, got {data['description']!r}")
    spp = _int("spp", data.get("spp", 4), 1, MAX_SPP)
    seeds = _int_list("seeds", data.get("seeds", [0]), 0)
    for keys, samples, rays in (("spp x shadow_rays", spp, max(shadow_rays)),
                                ("reference.spp x reference.shadow_rays", reference.spp, reference.shadow_rays)):
        if samples * rays > MAX_SEGMENTS_PER_PIXEL:
            _fail(keys, f"{samples} x {rays} is more than the {MAX_SEGMENTS_PER_PIXEL:,} shadow rays per pixel one "
                         "render takes: lower them")
    cells = len(scene_specs) * len(method_specs) * len(shadow_rays) * len(seeds)
    if cells > MAX_CELLS:
        _fail(where, f"{cells:,} cells (scenes x methods x shadow_rays x seeds) is more than a study runs (at most "
                     f"{MAX_CELLS:,}): split it into several experiments")
    rendered = any(spec.reference is None for spec in scene_specs)
    if rendered and reference.seed in seeds:
        _fail("reference.seed", f"{reference.seed} (the rendered reference's seed) is one of the cells' seeds "
                                "(seeds, or --seeds): a rendered reference must be independent of the renders it "
                                "judges (a cell with its samples would measure no error); choose other seeds, or set "
                                "[reference] seed")
    table_rays = data.get("table_shadow_rays", 16 if 16 in shadow_rays else max(shadow_rays))
    if _int("table_shadow_rays", table_rays) not in shadow_rays:
        _fail("table_shadow_rays", f"{table_rays} is not one of shadow_rays {list(shadow_rays)}")
    return Experiment(
        name=_plain_name("name", data["name"]) if "name" in data else
        re.sub(r"[^A-Za-z0-9._-]", "-", Path(source).stem).lstrip(".") or "experiment",
        description=data.get("description", ""),
        scenes=scene_specs, methods=method_specs, shadow_rays=tuple(sorted(shadow_rays)),
        spp=spp, seeds=seeds,
        reference=reference, baseline=baselines[0] if baselines else method_specs[0].name,
        resolution=resolution, target_relmse=None if target is None else float(target),
        table_shadow_rays=table_rays, timing_repeats=_int("timing_repeats", data.get("timing_repeats", 1), 1, 16),
        timing_seconds=_seconds("timing_seconds", data.get("timing_seconds", math.inf)),
        seconds=_choice("seconds", data.get("seconds", "total"), ("total", "render")))


def reference_noise_problem(exp):
    """The warning for a rendered reference that takes fewer samples a pixel than the study's largest cell (its
    own noise then makes most of the cells' relMSE), or None."""
    ref, cell = exp.reference, exp.spp * max(exp.shadow_rays)
    if all(spec.reference is not None for spec in exp.scenes) or ref.spp * ref.shadow_rays >= cell:
        return None
    return (f"experiment '{exp.name}': the rendered reference takes {ref.spp} x {ref.shadow_rays} samples a pixel, "
            f"fewer than the largest cell's {exp.spp} x {max(exp.shadow_rays)}: the cells' relMSE then measures "
            "mostly the reference's own noise; give [reference] spp and shadow_rays many times the cells'")


def recheck(exp):
    """An `Experiment` built or changed in Python (`dataclasses.replace`) checked as `parse_experiment` checks a
    file's: its fields as the table they came from, parsed again."""
    for field_name, kind in (("scenes", SceneSpec), ("methods", MethodSpec)):
        items = getattr(exp, field_name)
        if not isinstance(items, (tuple, list)) or not all(isinstance(x, kind) for x in items):
            _fail(field_name, f"expected a tuple of {kind.__name__}s, got {items!r}"[:300])
    if not isinstance(exp.reference, ReferenceSettings):
        _fail("reference", f"expected a ReferenceSettings, got {exp.reference!r}"[:300])
    if exp.baseline not in [m.name for m in exp.methods]:
        _fail("baseline", f"{exp.baseline!r} is not one of the methods ({', '.join(m.name for m in exp.methods)})")
    data = {"name": exp.name, "description": exp.description, "spp": exp.spp, "seeds": exp.seeds,
            "shadow_rays": exp.shadow_rays, "table_shadow_rays": exp.table_shadow_rays,
            "timing_repeats": exp.timing_repeats, "timing_seconds": exp.timing_seconds, "seconds": exp.seconds,
            "reference": dataclasses.asdict(exp.reference),
            "scenes": [{k: v for k, v in dataclasses.asdict(s).items()
                        if v is not None and (k != "reference_noise" or s.reference is not None)}
                       for s in exp.scenes],
            "methods": [dict(dataclasses.asdict(m), baseline=m.name == exp.baseline) for m in exp.methods]}
    data.update({k: v for k, v in (("resolution", exp.resolution), ("target_relmse", exp.target_relmse))
                 if v is not None})
    return parse_experiment(data, source=exp.name if isinstance(exp.name, str) else "")


MAX_DEPTH = 16  # lists and tables: an experiment nests three levels
MAX_TARGET = 1e6  # a target relMSE: beyond, every render reaches it (and its time extrapolates past float's range)
MAX_CELLS = 100_000  # renders of one study: its report lists every cell, its cache holds a file per render
HASHED_STEM = re.compile(r".*-[0-9a-f]{6}")  # what `file_stem` makes of a name it had to change


def file_stem(name):
    """The report's file name for a scene or method name: ASCII letters, digits, - and _. A name that had to be
    changed, or that already ends as a changed one does (a hyphen and six hex digits), gets a short hash of
    itself, so 'x/y', 'x_y' and 'x_y-<hash of x/y>' stay apart (`parse_experiment` refuses what still collides)."""
    out = "".join(c if (c.isascii() and c.isalnum()) or c in "-_" else "_" for c in name)
    if out != name or HASHED_STEM.fullmatch(name):
        out += "-" + hashlib.sha1(name.encode()).hexdigest()[:6]
    return out


MAX_NAME = 100  # characters: report files add a suffix, and file systems allow 255 bytes


def _plain_name(where, value):
    """A name that report files and folders are made of: letters, digits, '.', '_' and '-', not starting with '.'."""
    name = _str(where, value)
    if not re.fullmatch(r"[A-Za-z0-9_-][A-Za-z0-9._-]*", name):
        _fail(where, f"must be a plain name (letters, digits, '.', '_', '-'; it names files), got {name!r}")
    if len(name) > MAX_NAME:
        _fail(where, f"is {len(name)} characters long, more than a name of files and folders may be ({MAX_NAME})")
    return name


def _choice(where, value, choices):
    if value not in choices:
        _fail(where, f"expected one of {', '.join(choices)}, got {value!r}")
    return value


@checked_call
def load_experiment(path):
    """Read and validate an experiment TOML file."""
    if not is_path(path):
        raise ProbvisError(f"path must be an experiment file's path, got {type(path).__name__}")
    path = Path(os.fspath(path))
    if path.is_dir():
        raise ProbvisError(f"{path} is a folder, not an experiment file (.toml)")
    if not path.is_file():
        raise ProbvisError(missing_file(path, "experiment file"))
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8-sig"))  # a byte-order mark is allowed
    except UnicodeDecodeError:
        raise ProbvisError(f"{path}: not UTF-8 text (a TOML file is UTF-8): save it as UTF-8") from None
    except tomllib.TOMLDecodeError as exc:
        raise ProbvisError(f"{path}: malformed TOML: {exc}") from None
    except ValueError as exc:  # Python's own limits: an integer of more than 4300 digits
        raise ProbvisError(f"{path}: unreadable TOML: {str(exc).split(';')[0]}") from None
    except RecursionError:
        raise ProbvisError(f"{path}: unreadable TOML: arrays or tables nested too deep (an experiment nests "
                           "three levels)") from None
    return parse_experiment(data, path.resolve().parent, str(path))


@checked_call
def quick_experiment():
    """The `--quick` preset: built-in scenes, every method, small images; minutes on 2 cores."""
    text = resources.files(__package__).joinpath("quick.toml").read_text()
    return parse_experiment(tomllib.loads(text), Path("."), "quick.toml")
