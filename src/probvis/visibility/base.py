"""The visibility interface: an estimator turns a batch of shadow segments into real-valued visibility.

An estimator may return any real number per segment (probabilistic estimators return negative values); the
integrator multiplies it with the segment's unoccluded contribution, so an estimator is unbiased exactly when
the expectation of its value is the segment's binary visibility. `docs/writing-an-estimator.md` walks through
writing one.

An estimator class declares, the way a Mitsuba plugin does, its `name`, a one-line `summary`, its `options`
(name, type, default, help and validation: the CLI's flags, `probvis estimators` and experiment files all come
from them), the `phases` it times and the `aovs` it adds to the render.
"""
import abc
import enum
import math
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import ClassVar

import numpy as np

from ..cases import (CASE_LIT, CASE_MASK, CASE_NAMES, CASE_PENUMBRA, CASE_SHADOWED, CASE_UNKNOWN,  # noqa: F401
                     CASE_VERIFIED, N_CASES)
from ..errors import ProbvisError, is_flag, is_number, shown
from ..settings import parse_float, parse_int


class Switch:
    """An option type: a switch the estimator may also set itself. "on" and "off" force it, "auto" (usually the
    default) leaves the choice to the estimator; true/false, yes/no and 1/0 are read as on/off."""

    CHOICES = ("auto", "on", "off")


_TYPE_NAMES = {int: "integer", float: "number", str: "string", bool: "true/false", tuple: "numbers",
               Switch: " | ".join(Switch.CHOICES)}
OPTION_TYPES = tuple(_TYPE_NAMES)  # the types an `Option` can take


@dataclass(frozen=True)
class Option:
    """A setting of an estimator. `type` is int, float, str, bool, `Switch` or tuple (`count` comma-separated numbers);
    `default` None means the estimator picks a value itself (say how in `help`). Numbers are checked against
    `minimum` and `maximum`, strings against `choices`; `check(value)` may return an error message, which
    follows the option's name ("must be positive")."""

    name: str
    type: type
    default: object = None
    help: str = ""
    choices: tuple = ()
    minimum: float | None = None
    maximum: float | None = None
    count: int | None = None
    check: object = None
    metavar: str | None = None
    warm_up: object = None  # its value in the warm-up renders (`VisibilityEstimator.warm_ups`): a size, a switch of
    # caches or a threshold scaled to the warm-up's small meshes, never a choice the user's render does not make

    def __post_init__(self):
        """NumPy scalars among the declared values as Python's: they reach JSON (stats, `estimators --json`)."""
        for name in ("default", "minimum", "maximum", "warm_up"):
            value = getattr(self, name)
            if isinstance(value, np.generic):
                object.__setattr__(self, name, value.item())
        if isinstance(self.choices, tuple) and any(isinstance(c, np.generic) for c in self.choices):
            object.__setattr__(self, "choices", tuple(c.item() if isinstance(c, np.generic) else c
                                                      for c in self.choices))

    @property
    def flag(self):
        """The command-line flag, e.g. `--adaptive-photons` for `adaptive_photons`."""
        return "--" + self.name.replace("_", "-")

    def describe_type(self):
        if self.choices:
            return " | ".join(self.choices)
        if self.type is tuple:
            return f"{self.count} numbers"
        return _TYPE_NAMES[self.type]

    def parse(self, value):
        """The option's value from a command-line string or a Python/TOML value; ProbvisError if invalid."""
        v = self._convert(value)
        if self.choices and v not in self.choices:
            raise ProbvisError(f"{self.name} must be one of {', '.join(self.choices)}, got {value!r}")
        for x in (v if isinstance(v, tuple) else (v,)):
            if isinstance(x, (int, float)) and not isinstance(x, bool):
                if self.minimum is not None and x < self.minimum or self.maximum is not None and x > self.maximum:
                    raise ProbvisError(f"{self.name} must be {self._range()}, got {value!r}")
        if self.check is not None:
            try:
                message = self.check(v)
            except ProbvisError:  # the check's own refusal of the value, in its words
                raise
            except Exception as exc:  # noqa: BLE001 - a plug-in's check that fails on a value it was given
                raise ProbvisError(f"{self.name}: its check raised {type(exc).__name__} on {shown(value, repr)}: "
                                   f"{shown(exc)} (a bug in the estimator's option check)") from None
            if message and not isinstance(message, str):  # True for 'bad': say what the contract is
                raise ProbvisError(f"{self.name}: its check returned {shown(message, repr)} on {shown(value, repr)}, "
                                   "not an error message (a string) or None (a bug in the estimator's option check)")
            if message:
                raise ProbvisError(f"{self.name} {shown(message)}")
        return v

    def _range(self):
        lo, hi = self.minimum, self.maximum
        if hi is None:
            return f"at least {_show(lo)}"
        if lo is None:
            return f"at most {_show(hi)}"
        return f"from {_show(lo)} to {_show(hi)}"

    def _convert(self, value):
        text = repr(value)
        expected = self.describe_type() if self.choices or self.type not in (float, tuple) else (
            f"{self.count} finite numbers" if self.type is tuple else "a finite number")
        bad = ProbvisError(f"{self.name} expects {expected}, got "
                           f"{text if len(text) <= 60 else text[:50] + f'...({len(text)} characters)'}")
        if self.type is bool:
            if is_flag(value):
                return bool(value)
            if isinstance(value, str) and value.lower() in ("true", "false", "1", "0", "yes", "no", "on", "off"):
                return value.lower() in ("true", "1", "yes", "on")
            raise bad
        if self.type is Switch:
            word = ("on" if value else "off") if is_flag(value) else \
                _SWITCH_WORDS.get(value.strip().lower()) if isinstance(value, str) else None
            if word is None:
                raise bad
            return word
        if self.type is str:  # a number for a text option (a probability or a keyword): its text, as typed
            if isinstance(value, str):
                return value
            if is_number(value):
                return repr(float(value)) if isinstance(value, (float, np.floating)) else str(int(value))
            raise bad
        if self.type is tuple:
            items = value.split(",") if isinstance(value, str) else value
            if isinstance(items, np.ndarray) and items.ndim == 1:  # an array of numbers, as a list's
                items = items.tolist()
            if not isinstance(items, (list, tuple)) or len(items) != self.count:
                raise bad
            return tuple(_number(x, float, bad) for x in items)
        return _number(value, self.type, bad)


_SWITCH_WORDS = {"auto": "auto", "on": "on", "true": "on", "yes": "on", "1": "on", "off": "off", "false": "off",
                 "no": "off", "0": "off"}


def _show(x):
    return f"{int(x):,}" if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


def _number(value, kind, bad):
    """`value` (string or number) as a finite int or float; `bad` is raised otherwise."""
    if isinstance(value, (bool, np.bool_, np.timedelta64)):
        raise bad
    if isinstance(value, (np.integer, np.floating)):  # NumPy's numbers are numbers, as the render's arguments take them
        value = int(value) if isinstance(value, np.integer) else float(value)
    if isinstance(value, str):
        try:
            value = parse_float(value) if kind is float else parse_int(value)
        except ValueError:
            try:  # "1e5" for an integer is fine when it is whole
                value = parse_float(value)
            except ValueError:
                raise bad from None
    try:
        finite = isinstance(value, (int, float)) and math.isfinite(value)
    except OverflowError:  # an int beyond a float's range (10**400)
        finite = False
    if not finite:
        raise bad
    if kind is int:
        if value != int(value):
            raise bad
        return int(value)
    return float(value)


@dataclass(frozen=True)
class Phase:
    """A part of the estimator's work that it times: `stage` "prepare" (once per render, before the batches) or
    "batch" (summed over the batches)."""

    name: str
    stage: str
    help: str = ""


@dataclass(frozen=True)
class Aov:
    """An image the estimator adds to `RenderResult.aovs`. `kind` "cases": per pixel and emitter the share of
    camera samples in each occlusion case (from `classify`); "segment": per pixel the mean over camera
    samples of the sum of a per-segment value the estimator returns in `VisibilityResult.aovs[name]`."""

    name: str
    help: str = ""
    kind: str = "segment"


@dataclass
class ShadingPoints:
    """First hits of the camera samples in a batch; `normal` is the shading normal on the lit side."""

    position: np.ndarray  # (m, 3)
    normal: np.ndarray  # (m, 3)
    triangle: np.ndarray  # (m,) scene triangle id, -1 where nothing is shaded (a miss, a one-sided back face)
    key: np.ndarray  # (m,) uint64 rng key of the camera sample, for per-point random choices (see `probvis.rng`)
    albedo: np.ndarray = None  # (m, 3) diffuse reflectance (the renderer's surfaces are Lambertian)


@dataclass
class ShadowQuery:
    """Shadow segments origin + t * direction, t in (0, tmax), from shading points to emitter points."""

    origin: np.ndarray  # (n, 3), already offset off the surface
    direction: np.ndarray  # (n, 3), emitter point minus origin
    tmax: np.ndarray  # (n,)
    point: np.ndarray  # (n,) shading point (index into the batch's `ShadingPoints`), non-decreasing
    emitter: np.ndarray  # (n,) emitter id of the sampled point
    key: np.ndarray  # (n,) uint64 rng key, unique per segment, for stochastic estimators (see `probvis.rng`)
    weight: np.ndarray = None  # (n,) luminance of the unoccluded contribution, for efficiency-aware choices


@dataclass
class VisibilityResult:
    value: np.ndarray  # (n,) float64, the visibility estimate of each segment
    node_tests: np.ndarray  # (n,) ray-node tests made for the segment
    triangle_tests: np.ndarray  # (n,) ray-triangle tests made for the segment
    aovs: dict = field(default_factory=dict)  # name -> (n,) per-segment values of the declared "segment" AOVs


class RenderPath(enum.Enum):
    """How the integrator renders with an estimator, chosen once per render after `prepare`
    (`VisibilityEstimator.render_path`)."""

    STAGED = "staged"  # shadow segments made for the batch, `evaluate` on them, then the film
    FUSED_EXACT = "fused-exact"  # exact any-hit visibility: the integrator's fused kernel, same numbers as staged
    OWN_KERNEL = "own-kernel"  # the estimator renders each batch itself: `shade`


class VisibilityEstimator(abc.ABC):
    """Subclass it, declare `name`, `summary`, `options`, `phases` and `aovs`, and implement `evaluate`.

    Life of an estimator in a render: `__init__(**options)` validates the options into `self.params`;
    `prepare` runs once with the scene, its BVH, the emitter sampler, the render settings and the integrator;
    `render_path` then says how the batches are rendered. Per batch of pixels, `classify` (optional) sees the
    shading points before their segments are made; on the staged path `evaluate` estimates the segments'
    visibility, on its own path `shade` renders the batch. `stats` adds the estimator's measurements to the
    render's stats.
    """

    name: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    options: ClassVar[tuple] = ()
    phases: ClassVar[tuple] = ()
    aovs: ClassVar[tuple] = ()
    unbiased: ClassVar[bool] = True  # False for a consistent estimator: its stats and reports say "biased"
    # False where a pixel's camera samples share a factor (the ratio's): their spread then says nothing of the
    # image's noise, and the stats' noise_relmse is None
    independent_samples: ClassVar[bool] = True

    def __init__(self, **options):
        self.params = SimpleNamespace(**self.parse_options(options))
        self.seconds = {p.name: 0.0 for p in self.phases}

    @classmethod
    def given(cls, options, name):
        """Whether `options` set option `name` to other than its default. An option given at its default counts
        as unset: `settings()` hands every option back, defaults included."""
        value, default = options.get(name), next(o.default for o in cls.options if o.name == name)
        if value is None:
            return False
        if isinstance(default, str):  # a word: auto, mesh
            return str(value).strip().lower() != default.lower()
        try:
            return default is None or float(value) != float(default)
        except (TypeError, ValueError):
            return False  # parse_options names the bad value

    @classmethod
    def refuse_both(cls, options, first, second):
        """An error if `options` set both `first` and `second`, which exclude each other."""
        if cls.given(options, first) and cls.given(options, second):
            flags = [o.flag for name in (first, second) for o in cls.options if o.name == name]
            raise ProbvisError(f"visibility '{cls.name}': give {first} or {second}, not both (the command line's "
                               f"{' and '.join(flags)})")

    @classmethod
    def parse_options(cls, options):
        """Validate a dict of option values (strings or Python values) into the full dict of settings."""
        declared = {o.name: o for o in cls.options}
        unknown = sorted(set(options) - set(declared))
        if unknown:
            allowed = ", ".join(declared) or "none"
            raise ProbvisError(f"visibility '{cls.name}' has no option {', '.join(map(repr, unknown))} "
                               f"(its options: {allowed})")
        out = {}
        for name, opt in declared.items():
            value = options.get(name)
            out[name] = opt.default if value is None else opt.parse(value)
        return out

    @classmethod
    def warm_ups(cls, options, largest=None):
        """The options of the warm-up renders (`probvis.warm_up`, on a 4x4 scene of 132 triangles) that together
        run every kernel a render with `options` may run on a scene whose largest mesh that does not emit has
        `largest` triangles (None: any scene): by default one, with the sizes the options declare for it
        (`Option.warm_up`). Override to leave out an option that only makes sense at the real scene's scale (a
        length), or to add a render for kernels that only some scenes reach."""
        return [{**options, **{o.name: o.warm_up for o in cls.options if o.warm_up is not None}}]

    def settings(self):
        """The estimator's settings, as reported in the render stats."""
        return dict(vars(self.params))

    @contextmanager
    def timed(self, phase):
        """Add the block's wall time to declared phase `phase`."""
        if phase not in self.seconds:
            cls = type(self)
            raise ProbvisError(f"visibility '{self.name}' ({cls.__module__}.{cls.__qualname__}) times phase "
                               f"'{phase}', which it does not declare in `phases` ({', '.join(self.seconds)})")
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[phase] += time.perf_counter() - t0

    def prepare(self, scene, bvh, emitters, settings, integrator):
        """Build per-scene structures (timed as the render's "prepare" phase); keep what `evaluate` needs.
        `emitters` is the `EmitterSampler`; `integrator` the render's integrator, for estimators that render
        through a kernel of their own (`integrator.scene_arrays`, the kernels' scene) or measure a pilot
        (`integrator.shading_batch`, `integrator.shade_exact`)."""
        self.scene, self.bvh, self.emitters, self.render_settings = scene, bvh, emitters, settings
        self.integrator = integrator

    def render_path(self):
        """How the batches of this render are rendered (a `RenderPath`), asked once after `prepare`: STAGED by
        default; FUSED_EXACT only if `evaluate` returns exactly 1 - (any hit against the scene's BVH,
        traversed in packets of a shading point's segments); OWN_KERNEL if `shade` renders the batches."""
        return RenderPath.STAGED

    def classify(self, points: ShadingPoints):
        """Optionally an (m, n_emitters) int8 array of CASE_* per shading point and emitter: lit ones are
        integrated analytically, shadowed ones skipped, the others sampled; a lit or shadowed pair flagged
        CASE_VERIFIED is sampled as well, and its segments' values are corrections (see `probvis.cases`). Called per
        batch before the batch's segments are made; `evaluate` of the same batch follows. None samples all."""
        return None

    @abc.abstractmethod
    def evaluate(self, query: ShadowQuery) -> VisibilityResult:
        """Visibility estimates for a batch of segments."""

    def shade(self, batch):
        """On the OWN_KERNEL path: the `probvis.shading.ShadedBatch` of a `ShadingBatch` (each camera sample's
        radiance, per-pixel counts and segments), as the kernels of `probvis.shading` make it."""
        raise NotImplementedError(f"{type(self).__name__} renders through its own kernel but defines no shade()")

    def memory_estimate(self, scene, settings, batch_samples):
        """Bytes by part of the estimator's own structures (photons, look-ups, ...) for a render of `scene` with
        `settings` in batches of `batch_samples` camera samples; checked against the available memory before
        `prepare`. Name parts after what lowers them (see `probvis.memory`)."""
        return {}

    def memory_bytes(self):
        """Bytes by part of the estimator's own structures as built (proxies, shells, photons): what the
        render's memory estimate predicted, measured."""
        return {}

    def stats(self):
        """Measurements accumulated over the render: at least the seconds of each declared phase and the
        bytes of the estimator's own structures."""
        out = {"seconds": dict(self.seconds), "memory_bytes": self.memory_bytes()}
        return out if self.unbiased else {**out, "biased": True}
