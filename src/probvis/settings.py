"""Render settings: how many samples, which random sequence, how many threads — everything that is not the scene.

A scene file declares its own (Mitsuba's `sampler sample_count` and `seed`, the integrator's `emitter_samples`),
kept as `Scene.defaults`; `render` starts from those and replaces what the caller gives.
"""
import dataclasses
import numbers
import re
from dataclasses import dataclass

from .errors import ProbvisError, checked_call, is_flag, is_number

MAX_SPP = 1 << 20
MAX_SHADOW_RAYS = 1 << 16
MAX_SEGMENTS_PER_PIXEL = 1 << 26  # spp x shadow_rays: a batch holds at least one pixel, and an interrupt waits for
# its batch (2^26 segments take seconds; 2^36 took hours); more samples: average renders of several seeds
MAX_SEED = (1 << 63) - 1  # the kernels take the seed as a signed 64-bit integer

_INT = re.compile(r"\s*[+-]?[0-9]+\s*")
_FLOAT = re.compile(r"\s*[+-]?(?:(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|inf|infinity|nan)\s*", re.IGNORECASE)


def parse_int(text):
    """A whole number in the syntax Mitsuba's and C's parsers read: ASCII digits with an optional sign (Python's
    int() also takes '1_6' and other scripts' digits). ValueError otherwise."""
    if not isinstance(text, str) or not _INT.fullmatch(text):
        raise ValueError(f"not a whole number: {text!r}")
    return int(text)


def parse_float(text):
    """A number in C's decimal syntax (digits, point, exponent, inf, nan); ValueError otherwise."""
    if not isinstance(text, str) or not _FLOAT.fullmatch(text):
        raise ValueError(f"not a number: {text!r}")
    return float(text)


def whole_number(value):
    """Whether `value` is a whole number (an int, or a float or numpy number with no fraction), not a bool."""
    return (isinstance(value, numbers.Real) and is_number(value) and value == value
            and abs(value) != float("inf") and int(value) == value)


@dataclass(frozen=True)
class RenderSettings:
    """`spp` camera samples per pixel, `shadow_rays` emitter samples per camera sample, the random `seed`
    (the image is a pure function of it), `threads` (None: every core), and `filter_importance`: draw camera
    samples from the reconstruction filter, one pixel each, instead of splatting them as Mitsuba's film does."""

    spp: int = 4
    shadow_rays: int = 1
    seed: int = 0
    threads: int | None = None
    filter_importance: bool = False

    def __post_init__(self):
        self.validate()  # refused where it is made, not at a later render

    def replace(self, **changes):
        """A copy with the given settings replaced (and validated); None leaves a setting as it is."""
        names = [f.name for f in dataclasses.fields(self)]
        unknown = sorted(set(changes) - set(names))
        if unknown:
            raise ProbvisError(f"RenderSettings has no setting {', '.join(map(repr, unknown))} (its settings: "
                               f"{', '.join(names)})")
        return dataclasses.replace(self, **{k: v for k, v in changes.items() if v is not None})

    def check_budget(self):
        """A render's settings (after any overrides): at most MAX_SEGMENTS_PER_PIXEL shadow rays per pixel."""
        if self.spp * self.shadow_rays > MAX_SEGMENTS_PER_PIXEL:
            raise ProbvisError(f"spp x shadow_rays = {self.spp} x {self.shadow_rays} is more than the "
                               f"{MAX_SEGMENTS_PER_PIXEL:,} shadow rays per pixel one render takes: lower them, or "
                               "average renders with different seeds")
        return self

    def validate(self):
        for what, val, lo, hi in (("spp", self.spp, 1, MAX_SPP), ("shadow_rays", self.shadow_rays, 1, MAX_SHADOW_RAYS),
                                  ("seed", self.seed, 0, MAX_SEED)):
            if not whole_number(val) or not lo <= int(val) <= hi:
                raise ProbvisError(f"{what} must be a whole number from {lo} to {hi}, got {val!r}")
        if self.threads is not None and not (whole_number(self.threads) and self.threads >= 1):
            raise ProbvisError(f"threads must be a positive whole number, got {self.threads!r}")
        if not is_flag(self.filter_importance):
            raise ProbvisError(f"filter_importance must be True or False, got {self.filter_importance!r}")
        object.__setattr__(self, "filter_importance", bool(self.filter_importance))
        for name in ("spp", "shadow_rays", "seed", "threads"):  # numpy's or a float's whole numbers as Python ints,
            if getattr(self, name) is not None:  # whose arithmetic neither wraps nor rounds
                object.__setattr__(self, name, int(getattr(self, name)))
        return self


# a misspelt setting is named with its nearest, as the API's functions do
RenderSettings.__init__ = checked_call(RenderSettings.__init__, "RenderSettings")
