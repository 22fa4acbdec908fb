"""The render's statistics: one JSON-serialisable dict assembled from the scene, settings, estimator and pass."""
import numba

from . import __version__
from .cases import CASE_NAMES


def _case_stats(counts):
    """Shading point x emitter pairs per occlusion case, for estimators that classify."""
    total = max(1, sum(counts))
    return {name: {"count": c, "share": c / total} for name, c in zip(CASE_NAMES, counts)}


def render_stats(scene, settings, estimator, result, image, clamp, seconds, memory):
    """Stats of a finished render: `result` is the integrator's pass, `clamp` the negative-pixel report,
    `seconds` the phases (wall: total, load, compile, bvh, prepare, render; CPU: cpu_total, cpu_compile, cpu_render) and
    `memory` the estimate and the measured peak."""
    tot = result.film.totals()
    cam = scene.camera
    shadow_rays = result.shadow_rays
    render_s = seconds["render"]
    return {
        "probvis_version": __version__,
        "scene": scene.name,
        "source": scene.source,
        "inputs": [str(p) for p in scene.inputs],
        "width": cam.width,
        "height": cam.height,
        "spp": settings.spp,
        "shadow_rays_per_sample": settings.shadow_rays,
        "seed": settings.seed,
        "threads": numba.get_num_threads(),
        "film": {"filter": cam.rfilter, "splatting": result.film.rfilter is not None,
                 "filter_importance": settings.filter_importance, "seconds": result.film.seconds},
        "visibility": {"name": estimator.name, **estimator.settings()},
        "render_path": result.path.value,
        "seconds": seconds,
        "memory": memory,
        "triangles": scene.n_triangles,
        "dropped_degenerate_triangles": scene.dropped_degenerate,
        "emitters": scene.n_emitters,
        "camera_rays": cam.width * cam.height * settings.spp,
        "camera_hits": result.camera_hits,
        "shadow_rays": shadow_rays,
        "negative_estimates": tot["negative"],
        "negative_estimate_share": tot["negative"] / max(1, shadow_rays),
        "negative_pixels": clamp,
        "cases": _case_stats(result.cases) if result.cases is not None else None,
        "intersection_tests": {
            "triangle": tot["cam_tri"] + tot["sh_tri"],
            "node": tot["cam_node"] + tot["sh_node"],
            "camera": {"triangle": tot["cam_tri"], "node": tot["cam_node"]},
            "shadow": {"triangle": tot["sh_tri"], "node": tot["sh_node"],
                       "triangle_per_ray": tot["sh_tri"] / max(1, shadow_rays),
                       "node_per_ray": tot["sh_node"] / max(1, shadow_rays)},
        },
        "shadow_rays_per_second": shadow_rays / render_s if render_s > 0 else None,
        "image_mean": [float(x) for x in image.reshape(-1, 3).mean(axis=0)],
        "noise_relmse": result.film.noise_relmse() if estimator.independent_samples else None,
        "bvh": result.bvh.stats(),
        "estimator": estimator.stats(),
    }
