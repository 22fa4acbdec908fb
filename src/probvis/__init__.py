"""probvis: direct illumination with measurable, replaceable visibility estimators."""
import os

# Numba's OpenMP threads spin for a long while (libgomp's default) between parallel regions: on a busy machine
# that costs renders 3-7x instead of the fair 2x. A short spin keeps idle speed and is fair under contention
# (bench/bench_contention.py, docs/decisions.md). Set before the OpenMP runtime loads; a user's value wins.
os.environ.setdefault("GOMP_SPINCOUNT", "1000")

from .errors import ProbvisError, checked_call  # noqa: E402

__version__ = "0.1.0"

_LAZY = {"BUILTINS": ".scene", "Scene": ".scene", "load_scene": ".scene", "RenderSettings": ".settings"}


def __getattr__(name):
    """The API's names load their modules (numpy, Numba) on first use, so `import probvis` and the console
    command start light and can report a failed start in one line (`probvis.__main__`)."""
    if name not in _LAZY:
        raise AttributeError(f"module 'probvis' has no attribute '{name}'")
    import importlib

    value = getattr(importlib.import_module(_LAZY[name], __name__), name)
    globals()[name] = value
    return value


@checked_call
def render(scene, settings=None, **kwargs):
    """Render `scene` (a `Scene`, an XML path or a built-in name); see `probvis.integrator.render`."""
    from .integrator import render as _render

    return _render(scene, settings, **kwargs)


__all__ = ["BUILTINS", "ProbvisError", "RenderSettings", "Scene", "load_scene", "render", "__version__"]
