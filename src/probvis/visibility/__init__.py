"""Visibility estimators, found by name: the built-ins, classes of installed packages registered under the
entry-point group `probvis.visibility`, and any importable class given as `package.module:Class` (or
`path/to/file.py:Class`)."""
import importlib
import importlib.util
import inspect
import math
import re
import sys
import threading
import unicodedata
from importlib.metadata import entry_points
from pathlib import Path

from ..errors import ProbvisError, is_builtin, shown
from .base import (CASE_LIT, CASE_NAMES, CASE_PENUMBRA, CASE_SHADOWED, CASE_UNKNOWN, N_CASES, OPTION_TYPES, Aov,
                   Option, Phase, RenderPath, ShadingPoints, ShadowQuery, Switch, VisibilityEstimator, VisibilityResult)

ENTRY_POINT_GROUP = "probvis.visibility"
BUILTIN = {
    "exact": "probvis.visibility.exact:ExactVisibility",
    "occlusion-map": "probvis.visibility.occlusion_map:OcclusionMapVisibility",
    "probvis": "probvis.visibility.probabilistic:ProbabilisticVisibility",
    "proxy": "probvis.visibility.proxy:ProxyVisibility",
    "nee++": "probvis.visibility.nee:NEEPlusPlusVisibility",
    "cache-cv": "probvis.visibility.cache_cv:CacheControlVariateVisibility",
    "ratio": "probvis.visibility.ratio:RatioVisibility",
}


_IMPORTING = threading.RLock()  # renders started from several threads import their estimators one at a time


def _load(spec, what):
    """The class named by `module:Class` or `file.py:Class`."""
    with _IMPORTING:
        return _load_unlocked(spec, what)


def _load_unlocked(spec, what):
    module_name, _, class_name = spec.rpartition(":")
    if not module_name or not class_name:
        raise ProbvisError(f"{what}: expected a name ({', '.join(available_names())}) or module:Class, got '{spec}'")
    if module_name in BUILTIN:  # `exact:shells=off`, as if options followed the name
        raise ProbvisError(f"{what}: '{spec}' is not an estimator: '{module_name}' is a built-in one, whose options "
                           f"are flags of their own (`probvis estimators {module_name}` lists them; in Python, "
                           "visibility_options); module:Class names a plug-in")
    try:
        if module_name.endswith(".py"):
            try:  # `--visibility=~/x.py:C`: the shell leaves ~ there
                path = Path(module_name).expanduser().resolve()
            except RuntimeError:
                raise ProbvisError(f"{what}: '{module_name}' names the home of a user this machine does not know")
            if not path.is_file():
                raise ProbvisError(f"{what}: {path} is a folder, not a Python file" if path.is_dir() else
                                   f"{what}: {path} is not a regular file (a pipe, socket or device)"
                                   if path.exists() else f"{what}: no file {path}")
            name = "probvis_plugin_" + path.stem
            if str(path.parent) not in sys.path:  # as `python file.py` would: the modules beside it import
                sys.path.append(str(path.parent))
            module = sys.modules.get(name)
            if module is None or getattr(module, "__file__", None) != str(path):
                mspec = importlib.util.spec_from_file_location(name, path)
                module = importlib.util.module_from_spec(mspec)
                sys.modules[name] = module
                mspec.loader.exec_module(module)
        else:
            if Path(module_name).is_file() or not all(part.isidentifier() for part in module_name.split(".")):
                raise ProbvisError(f"{what}: '{module_name}' is neither a module name (package.module) nor a Python "
                                   "file (.py): give module:Class or path/to/file.py:Class")
            if "" not in sys.path and str(Path.cwd()) not in sys.path:
                sys.path.append(str(Path.cwd()))  # as `python -m` would: modules beside the user
            module = importlib.import_module(module_name)
    except ProbvisError:
        raise
    except (Exception, SystemExit) as exc:  # an import error of any kind in the user's module, or its exit
        raise ProbvisError(f"{what}: cannot import '{module_name}': {type(exc).__name__}: {shown(exc)}") from None
    cls = getattr(module, class_name, None)
    if cls is None:
        raise ProbvisError(f"{what}: '{module_name}' defines no '{class_name}'")
    return _estimator_subclass(cls, spec, what)


def _estimator_subclass(cls, spec, what):
    """`cls` if it is a named `VisibilityEstimator` subclass (`spec` says where it came from)."""
    if not (isinstance(cls, type) and issubclass(cls, VisibilityEstimator)):
        raise ProbvisError(f"{what}: '{spec}' is not a probvis.visibility.VisibilityEstimator subclass")
    if not cls.name:
        raise ProbvisError(f"{what}: '{spec}' declares no name")
    return cls


# options of `probvis render` itself: an estimator's option of the same name would clash with its flag
RESERVED_OPTIONS = {"output", "define", "defines", "seed", "spp", "shadow_rays", "strict", "visibility", "case_image",
                    "filter_importance", "clamp_negative", "stats", "tests_image", "threads", "exposure", "quiet",
                    "help", "scene", "command"}

# a study's time by phase (`experiments.results.phases`) and the film's AOVs: an estimator's of the same name would
# replace probvis's own
RESERVED_PHASES = ("load", "bvh_build", "prepare", "prepare_other", "render")
RESERVED_AOVS = ("triangle_tests", "node_tests", "second_moment", "cases")


def _entry_points():
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def available_names():
    """Names of the built-in and installed estimators."""
    return list(BUILTIN) + [n for n in _entry_points() if n not in BUILTIN]


def estimator_class(name, what="visibility"):
    """The estimator class for a built-in or installed name, `module:Class` or `file.py:Class` (or a class);
    refused unless it implements every abstract method."""
    cls = _estimator_class(name, what)
    if inspect.isabstract(cls):
        missing = ", ".join(sorted(cls.__abstractmethods__))
        raise ProbvisError(f"{what}: {cls.__module__}.{cls.__qualname__} does not implement {missing} (see "
                           "docs/writing-an-estimator.md)")
    _check_declarations(cls, what)
    return cls


def _check_declarations(cls, what):
    """A plug-in's options as the command line and `parse` will take them: distinct names, none of probvis's own
    flags, defaults their own checks accept."""
    where = f"{what}: {cls.__module__}.{cls.__qualname__}"
    own = is_builtin(cls)
    # exactly str, here and below: a subclass's own __str__ or __format__ could fail wherever it is printed
    if type(cls.name) is not str or not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.+-]*", cls.name):
        raise ProbvisError(f"{where}: name must be one word (letters, digits, '-', '_', '.', '+'), got "
                           f"{shown(cls.name, repr)}")
    if not own and cls.name in BUILTIN and "name" in vars(cls):  # a subclass may keep its built-in parent's
        raise ProbvisError(f"{where}: name '{cls.name}' is a built-in estimator's: choose another, so its stats and "
                           "reports are not taken for the built-in's")
    for field, kind in (("options", Option), ("phases", Phase), ("aovs", Aov)):
        value = getattr(cls, field)
        if not isinstance(value, (tuple, list)) or not all(isinstance(x, kind) for x in value):
            raise ProbvisError(f"{where}: {field} must be a tuple of {kind.__name__}s, got {shown(value, repr)}"[:300])
    if not isinstance(cls.unbiased, bool):
        raise ProbvisError(f"{where}: unbiased must be True or False, got {shown(cls.unbiased, repr)}")
    for kind, xs in (("option", cls.options), ("phase", cls.phases), ("AOV", cls.aovs)):
        for x in xs:
            if type(x.name) is not str or not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", x.name):
                raise ProbvisError(f"{where}: {kind} names are identifiers (letters, digits, '_'), got "
                                   f"{shown(x.name, repr)}")
        names = [x.name for x in xs]
        if kind != "option" and len(set(names)) < len(names):
            raise ProbvisError(f"{where} declares {kind} '{next(n for n in names if names.count(n) > 1)}' twice")
    texts = [("summary", cls.summary)] + [(f"{kind} '{x.name}': help", x.help) for kind, xs in
                                           (("option", cls.options), ("phase", cls.phases), ("AOV", cls.aovs))
                                           for x in xs]
    for field, text in texts:
        if type(text) is not str or any(unicodedata.category(c)[0] == "C" for c in text):
            raise ProbvisError(f"{where}: {field} must be one line of plain text, got {shown(text, repr)}"[:300])
    for phase in cls.phases:
        if phase.stage not in ("prepare", "batch"):
            raise ProbvisError(f"{where}: phase '{phase.name}' has stage {shown(phase.stage, repr)} (prepare or "
                               "batch)")
        if phase.name in RESERVED_PHASES:
            raise ProbvisError(f"{where}: phase '{phase.name}' is one of probvis's own ({', '.join(RESERVED_PHASES)}) "
                               "in a study's time by phase: rename it")
    for aov in cls.aovs:
        if aov.kind not in ("cases", "segment"):
            raise ProbvisError(f"{where}: AOV '{aov.name}' has kind {shown(aov.kind, repr)} (cases or segment)")
        if aov.kind == "segment" and aov.name in RESERVED_AOVS:
            raise ProbvisError(f"{where}: AOV '{aov.name}' is one of the film's own ({', '.join(RESERVED_AOVS)}): "
                               "rename it")
        if aov.kind == "cases" and (aov.name != "cases" or cls.classify is VisibilityEstimator.classify):
            raise ProbvisError(f"{where}: a 'cases' AOV is the film's case shares, named 'cases', from the "
                               f"estimator's classify (got '{aov.name}'"
                               f"{'' if cls.classify is not VisibilityEstimator.classify else ', no classify'})")
    names, flags = [o.name for o in cls.options], {}
    for o in cls.options:
        if o.type not in OPTION_TYPES:
            raise ProbvisError(f"{where}: option '{o.name}' has type {getattr(o.type, '__name__', o.type)!r}, which "
                               "an option cannot take (int, float, str, bool, Switch or tuple)")
        if names.count(o.name) > 1:
            raise ProbvisError(f"{where} declares option '{o.name}' twice")
        if o.name in RESERVED_OPTIONS:
            raise ProbvisError(f"{where}: option '{o.name}' ({o.flag}) clashes with probvis's own {o.flag} (rename it)")
        if o.type is tuple and not (isinstance(o.count, int) and not isinstance(o.count, bool) and o.count > 0):
            raise ProbvisError(f"{where}: option '{o.name}' is a tuple and needs count, how many numbers it takes")
        _check_limits(where, o)
        for flag in [o.flag] + (["--no-" + o.flag[2:]] if o.type in (bool, Switch) else []):
            if flags.setdefault(flag, o.name) != o.name:
                raise ProbvisError(f"{where}: options '{flags[flag]}' and '{o.name}' both make the flag {flag}")
        if o.default is not None:
            try:
                parsed = o.parse(o.default)
            except ProbvisError as exc:
                raise ProbvisError(f"{where}: the default of option '{o.name}' is invalid: {exc}") from None
            except Exception as exc:  # the plug-in's own check failed on its default
                raise ProbvisError(f"{where}: option '{o.name}': its check raised {type(exc).__name__} on the default "
                                   f"{shown(o.default, repr)}: {shown(exc)}") from None
            if not (_DEFAULT_TYPES[o.type](o.default) and parsed == o.default):  # reaches the estimator as written
                raise ProbvisError(f"{where}: the default of option '{o.name}' is {shown(o.default, repr)} (type "
                                   f"{type(o.default).__name__}), not a value of the option's type: write {parsed!r}")


def _check_limits(where, o):
    """An option's choices (words, for a text option) and range (numbers, for a numeric one, not reversed)."""
    if o.choices and not (o.type is str and isinstance(o.choices, (tuple, list))
                          and all(type(c) is str for c in o.choices)):
        raise ProbvisError(f"{where}: option '{o.name}': choices must be a tuple of words for a str option, got "
                           f"{shown(o.choices, repr)} for a {getattr(o.type, '__name__', o.type)} option"[:300])
    for bound in ("minimum", "maximum"):
        value = getattr(o, bound)
        if value is not None and not (o.type in (int, float, tuple) and isinstance(value, (int, float))
                                      and not isinstance(value, bool) and math.isfinite(value)):
            raise ProbvisError(f"{where}: option '{o.name}': {bound} must be a finite number for an int, float or "
                               f"tuple option, got {shown(value, repr)} for a {getattr(o.type, '__name__', o.type)} "
                               "option"[:300])
    if o.minimum is not None and o.maximum is not None and o.minimum > o.maximum:
        raise ProbvisError(f"{where}: option '{o.name}': minimum {o.minimum:g} is above maximum {o.maximum:g}: no "
                           "value would be accepted")


# the Python values an option's default may be: it reaches the estimator as declared, unparsed
_DEFAULT_TYPES = {bool: lambda d: isinstance(d, bool), int: lambda d: isinstance(d, int) and not isinstance(d, bool),
                  float: lambda d: isinstance(d, (int, float)) and not isinstance(d, bool),
                  str: lambda d: isinstance(d, str), Switch: lambda d: d in Switch.CHOICES,
                  tuple: lambda d: isinstance(d, tuple)}


def _estimator_class(name, what):
    if isinstance(name, type):
        if not issubclass(name, VisibilityEstimator):
            raise ProbvisError(f"{what}: {name!r} is not a VisibilityEstimator subclass")
        return name
    if not isinstance(name, str):
        raise ProbvisError(f"{what}: expected an estimator name, got {name!r}")
    if name in BUILTIN:
        return _load(BUILTIN[name], what)
    eps = _entry_points()
    if name in eps:
        try:
            with _IMPORTING:
                cls = eps[name].load()
        except (Exception, SystemExit) as exc:  # its import failed, or called sys.exit
            raise ProbvisError(f"{what}: cannot load installed estimator '{name}' ({eps[name].value}): "
                               f"{type(exc).__name__}: {shown(exc)}") from None
        return _estimator_subclass(cls, f"{eps[name].value}", what)
    if ":" in name:
        return _load(name, what)
    raise ProbvisError(f"unknown {what} '{name}' (available: {', '.join(available_names())}, or module:Class or "
                       "file.py:Class)")


def make_estimator(name, **options):
    """An estimator instance from a name (see `estimator_class`) and its options; an instance is returned as is."""
    if isinstance(name, VisibilityEstimator):
        if options:
            raise ProbvisError("options apply to an estimator name or class, not to an instance")
        return name
    return estimator_class(name)(**options)


__all__ = ["BUILTIN", "CASE_LIT", "CASE_NAMES", "CASE_PENUMBRA", "CASE_SHADOWED", "CASE_UNKNOWN", "ENTRY_POINT_GROUP",
           "N_CASES", "Aov", "Option", "Phase", "RenderPath", "ShadingPoints", "ShadowQuery", "VisibilityEstimator",
           "VisibilityResult", "available_names", "estimator_class", "make_estimator"]
