"""Render statistics: JSON files and the short summary the CLI prints."""
import json

from ..errors import ProbvisError
from .atomic import atomic_path


def write_stats(path, stats):
    """`stats` (a dict: a render's, or a study's) as JSON; a value JSON cannot hold (NaN, infinity, an object) is
    refused, nothing written."""
    if not isinstance(stats, dict):
        raise ProbvisError(f"cannot write '{path}': stats are a dict (RenderResult.stats), got {type(stats).__name__}")
    try:
        text = json.dumps(stats, indent=2, allow_nan=False) + "\n"
    except (TypeError, ValueError) as exc:
        raise ProbvisError(f"cannot write '{path}': the stats hold a value JSON cannot hold ({exc})") from None
    except RecursionError:
        raise ProbvisError(f"cannot write '{path}': the stats nest too deep") from None
    with atomic_path(path) as tmp:
        with open(tmp, "w") as f:
            f.write(text)


def biased_by_choice(stats):
    """Whether a render is biased by construction (a consistent estimator such as `ratio`, verification off,
    negative pixels clamped): such renders are labelled biased in the summary and in reports."""
    estimator = stats.get("estimator") or {}
    verification = estimator.get("verification") or {}
    return (bool(estimator.get("biased")) or bool(verification.get("biased"))
            or bool(stats["negative_pixels"].get("clamped")))


def summary(stats):
    """The lines `probvis render` prints of a render's `stats` (`RenderResult.stats`)."""
    if not isinstance(stats, dict):
        raise ProbvisError(f"summary takes a render's stats (RenderResult.stats, a dict), got "
                           f"{type(stats).__name__}")
    try:
        return _summary(stats)
    except KeyError as exc:
        raise ProbvisError(f"summary takes a render's stats (RenderResult.stats); this dict lacks {exc}") from None
    except (TypeError, ValueError) as exc:
        raise ProbvisError(f"summary takes a render's stats (RenderResult.stats); a value of this dict has the "
                           f"wrong type ({exc})") from None


def _summary(stats):
    s = stats["seconds"]
    it = stats["intersection_tests"]
    lines = [
        f"scene       {stats['scene']}  {stats['width']}x{stats['height']}, {stats['spp']} spp x "
        f"{stats['shadow_rays_per_sample']} shadow rays, seed {stats['seed']}, visibility {stats['visibility']['name']}"
        + (" (biased: at these settings its expectation is not exact visibility's image)"
           if biased_by_choice(stats) else ""),
        f"seconds     total {s['total']:.2f} = load {s['load']:.2f} + compile {s['compile']:.2f} + "
        f"bvh {s['bvh']:.2f} + prepare {s['prepare']:.2f} + render {s['render']:.2f}",
        f"rays        camera {stats['camera_rays']:,}  shadow {stats['shadow_rays']:,}"
        + (f"  ({stats['shadow_rays_per_second'] / 1e6:.2f} M/s)" if stats["shadow_rays_per_second"] else ""),
        f"tests       triangle {it['triangle']:,}  node {it['node']:,}  "
        f"(shadow: triangle {it['shadow']['triangle']:,}, node {it['shadow']['node']:,}; per shadow ray "
        f"{it['shadow']['triangle_per_ray']:.3g} triangle, {it['shadow']['node_per_ray']:.3g} node)",
        "image mean  " + ", ".join(f"{x:.5g}" for x in stats["image_mean"]),
    ]
    return "\n".join(lines)
