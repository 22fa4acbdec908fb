"""probvis: direct illumination with measurable, replaceable visibility estimators."""
import os

# Numba's OpenMP threads spin for a long while (libgomp's default) between parallel regions: on a busy machine
# that costs renders 3-7x instead of the fair 2x. A short spin keeps idle speed and is fair under contention
# (bench/bench_contention.py, docs/decisions.md). Set before the OpenMP runtime loads; a user's value wins.
os.environ.setdefault("GOMP_SPINCOUNT", "1000")

from .errors import ProbvisError  # noqa: E402
from .scene import BUILTINS, Scene, load_scene  # noqa: E402
from .settings import RenderSettings  # noqa: E402

__version__ = "0.1.0"


def render(scene, settings=None, **kwargs):
    """Render `scene` (a `Scene`, an XML path or a built-in name); see `probvis.integrator.render`."""
    from .integrator import render as _render

    return _render(scene, settings, **kwargs)


__all__ = ["BUILTINS", "ProbvisError", "RenderSettings", "Scene", "load_scene", "render", "__version__"]
