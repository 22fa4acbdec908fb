"""probvis: direct illumination with measurable, replaceable visibility estimators."""
from .errors import ProbvisError
from .scene import BUILTINS, Scene, load_scene
from .settings import RenderSettings

__version__ = "0.1.0"


def render(scene, settings=None, **kwargs):
    """Render `scene` (a `Scene`, an XML path or a built-in name); see `probvis.integrator.render`."""
    from .integrator import render as _render

    return _render(scene, settings, **kwargs)


__all__ = ["BUILTINS", "ProbvisError", "RenderSettings", "Scene", "load_scene", "render", "__version__"]
