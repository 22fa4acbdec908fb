"""Scenes: Mitsuba XML files or built-in procedural scenes, loaded into flat triangle arrays."""
import numbers
import os
import warnings
from pathlib import Path

from ..errors import ProbvisError, checked_call, is_flag, is_path
from ..io.linear_rgb import READ_FORMATS
from .builtin import BUILTINS, builtin_scene
from .mitsuba_xml import read_scene
from .scene import Scene, SceneBuilder, ShapeInfo
from .sensor import Camera


@checked_call
def load_scene(path, /, strict=False, **defaults):
    """Load a Mitsuba 3 XML file, or a built-in scene by name (`probvis scenes` lists them).

    Keyword arguments override the scene's `<default>` parameters, like Mitsuba's `-D name=value`; with `strict`
    appearance probvis would approximate (a non-diffuse BSDF) is an error instead of a warning. (A parameter
    named `strict` is given through `open_scene`.)
    """
    return open_scene(path, defaults, strict)


def open_scene(path, defines, strict=False):
    """`load_scene` with the parameters as a dict `defines`: any name, `path` and `strict` included (the command
    line's `-D`, an experiment's `defines`)."""
    defaults = dict(defines)
    if not is_path(path):
        raise ProbvisError(f"path must be a scene file path or a built-in name, got {type(path).__name__}")
    path = path if isinstance(path, str) else Path(os.fspath(path))  # a path object names a file, not a built-in
    if not is_flag(strict):
        raise ProbvisError(f"strict must be True or False, got {strict!r}")
    strict = bool(strict)
    if any(not (isinstance(k, str) and k.strip()) for k in defaults):
        raise ProbvisError("defines: a parameter name is empty (each is name=value)")
    for name, value in defaults.items():  # `defines={...}` would be one parameter named "defines"
        if not isinstance(value, (str, numbers.Real)):
            raise ProbvisError(f"parameter {name}={value!r}: a scene parameter's value is a string or a number; "
                               "give each parameter its own: load_scene(path, name=value, ...), or "
                               "render(path, defines={'name': value, ...})")
    if not str(path).strip():
        raise ProbvisError(f"the scene name is empty: give a scene file or a built-in scene ({', '.join(BUILTINS)})")
    if isinstance(path, str) and path.lstrip().startswith("<") and not os.path.exists(path):  # it was quoted back
        start = " ".join(path[:200].split())[:30]
        raise ProbvisError(f"the scene is given as XML text ({len(path):,} characters, '{start}...'): probvis reads "
                           "scene files: save the text to a file and give its path")
    try:
        if isinstance(path, str) and path in BUILTINS:
            if Path(path).is_file():
                warnings.warn(f"'{path}' names a built-in scene and a file here: rendering the built-in (give "
                              f"./{path} for the file)", stacklevel=2)
            return builtin_scene(path, defaults)
        p = Path(path)
        if p.suffix.lower() != ".xml" and not p.exists():
            if str(path) in BUILTINS:
                raise ProbvisError(f"{path!r} is not a scene file here; a built-in scene is named by a string: "
                                   f"'{path}'")
            raise ProbvisError(f"'{path}' is neither a scene file nor a built-in scene ({', '.join(BUILTINS)})")
    except OSError as exc:
        name = str(path) if len(str(path)) <= 80 else f"{str(path)[:60]}...({len(str(path))} characters)"
        raise ProbvisError(f"scene '{name}': {exc.strerror or exc}") from None
    except MemoryError:
        raise ProbvisError(f"out of memory building the built-in scene '{path}' (the machine's or the process's "
                           "limit, ulimit -v): raise the limit, or use a smaller scene") from None
    kind = p.suffix.lower()[1:]
    if kind in ("obj", "ply", "serialized"):  # was "malformed XML: syntax error"
        raise ProbvisError(f"{p} is a mesh, not a scene: a scene is a Mitsuba XML file that places it (a <shape "
                           f"type=\"{kind}\">, with a sensor and an emitter), or a built-in scene")
    if p.suffix.lower() in READ_FORMATS:
        raise ProbvisError(f"{p} is an image, not a scene: a scene is a Mitsuba XML file (an image can be its "
                           "envmap's or a bitmap texture's filename), or a built-in scene")
    if kind == "toml":
        raise ProbvisError(f"{p} is an experiment file, not a scene: run it with `probvis experiment {p}`")
    try:
        return read_scene(p, strict, defaults)
    except MemoryError:
        raise ProbvisError(f"out of memory loading {p} (the machine's or the process's limit, ulimit -v): its "
                           "meshes and images need more; raise the limit") from None


__all__ = ["BUILTINS", "Camera", "Scene", "SceneBuilder", "ShapeInfo", "load_scene", "open_scene"]
