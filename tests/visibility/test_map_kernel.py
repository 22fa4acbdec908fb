"""The occlusion map's kernel against the staged path: the same estimators, value for value.

The kernel (`occlusion_map.kernel.shade_map`) evaluates a shading point's segments together (the pair's
segments in one pass over a list or group, the BVH traces in packets); the staged path (`evaluate`) does it
batch-wide in NumPy. Same random draws, same tests in the same order: images, per-pixel counts, negative
estimates and the estimators' counters agree exactly, with and without verification.
"""
import numpy as np
import pytest

import probvis
from probvis.visibility import RenderPath, estimator_class

CONFIGS = {
    "om-bvh": ("occlusion-map", {}),
    "om-list": ("occlusion-map", {"penumbra": "list"}),
    "om-list-q": ("occlusion-map", {"penumbra": "list", "verify": "0.5"}),
    "om-list-q1": ("occlusion-map", {"penumbra": "list", "verify": "1"}),
    "standard": ("probvis", {}),
    "shifted-q": ("probvis", {"estimator": "shifted", "verify": "0.3"}),
    "shifted-q1": ("probvis", {"estimator": "shifted", "verify": "1"}),
    "adaptive": ("probvis", {"estimator": "adaptive"}),
    "power-off": ("probvis", {"estimator": "power", "verify": "off"}),
    "levels": ("probvis", {"levels": 2, "grouping": "random"}),
    "cells": ("probvis", {"cells": 2, "verify": "0.5"}),
}
STAT_KEYS = ("culled_candidates", "penumbra_shadow_rays", "unknown_shadow_rays", "term_selections",
             "exact_selections")


def staged(name):
    """The estimator named `name` on the staged path."""
    base = estimator_class(name)
    return type(f"Staged{base.__name__}", (base,), {"render_path": lambda self: RenderPath.STAGED})


@pytest.mark.parametrize("scene", ["cornell-box", "canopy"])
@pytest.mark.parametrize("label", CONFIGS)
def test_kernel_renders_what_the_staged_path_renders(scene, label):
    name, options = CONFIGS[label]
    options = {"photons": 20000, **options}
    kw = dict(spp=2, shadow_rays=6, seed=3, defines={"res": 20})
    fused = probvis.render(scene, visibility=name, visibility_options=options, **kw)
    reference = probvis.render(scene, visibility=staged(name), visibility_options=options, **kw)
    assert fused.stats["render_path"] == "own-kernel" and reference.stats["render_path"] == "staged"
    np.testing.assert_array_equal(fused.image, reference.image)
    for aov in ("triangle_tests", "node_tests", "second_moment", "cases"):
        np.testing.assert_array_equal(fused.aovs[aov], reference.aovs[aov])
    assert fused.stats["intersection_tests"] == reference.stats["intersection_tests"]
    assert fused.stats["negative_estimates"] == reference.stats["negative_estimates"]
    got, want = fused.stats["estimator"], reference.stats["estimator"]
    for key in STAT_KEYS:
        assert got.get(key) == want.get(key), key
    for case in ("lit", "shadowed", "penumbra"):
        a, b = got["verification"][case], want["verification"][case]
        assert ((a["segments"], a["verified_segments"], a["measured_segments"]) ==
                (b["segments"], b["verified_segments"], b["measured_segments"])), case
        for k in ("mismatch_mean", "mismatch_variance", "mean_q"):
            assert a[k] == pytest.approx(b[k], rel=1e-9, abs=1e-12), (case, k)
    assert fused.stats["shadow_rays"] > 0 and got["penumbra_shadow_rays"] > 0


def test_kernel_phases_split_the_kernel_time():
    """The kernel's phases (cycle shares of its wall time) are reported, positive where there is work."""
    r = probvis.render("canopy", spp=2, shadow_rays=8, seed=1, defines={"res": 24}, visibility="probvis",
                       visibility_options={"photons": 20000})
    sec = r.stats["estimator"]["seconds"]
    for phase in ("sampling", "term_choice", "candidate_tests", "exact_traces", "verification_traces", "film"):
        assert sec[phase] >= 0.0
    assert sec["candidate_tests"] > 0.0 and sec["sampling"] > 0.0
    assert sum(sec[p] for p in ("sampling", "term_choice", "candidate_tests", "exact_traces",
                                "verification_traces", "film")) <= r.stats["seconds"]["render"]
