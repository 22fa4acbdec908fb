"""Images, AOVs and test counts of every estimator on the built-in scenes, against stored hashes.

The hashes were made before the code was reorganised into plug-in estimators and named stages (the occlusion map
without verification, as it was then) and kept through the render paths' reorganisation and the occlusion map's own
kernel; probvis's split of whole blocker groups into A and B (instead of single triangles) changed the `pv-*` hashes
of the scenes with small closed components, and numbering the shared look-ups by one packed key (another order of
the pairs) changed `pv-cells`, whose random grouping draws by pair index. A change that alters any number here (on
purpose) must say so and store new hashes (`python3 tests/test_golden.py --store`).
"""
import hashlib
import json
import sys
from pathlib import Path

import numpy as np
import pytest

import probvis

STORED = Path(__file__).with_name("data") / "golden_builtin.json"
SCENES = ("cornell-box", "canopy", "box-city", "quad-shadow")
CONFIGS = {
    "exact": ("exact", {}),
    "om-bvh": ("occlusion-map", {"photons": 20000, "verify": "off"}),
    "om-list": ("occlusion-map", {"photons": 20000, "verify": "off", "penumbra": "list"}),
    "om-list-adaptive": ("occlusion-map", {"photons": 20000, "verify": "off", "penumbra": "list", "adaptive_photons": True}),
    "om-list-novol": ("occlusion-map", {"photons": 20000, "verify": "off", "penumbra": "list", "volumetric": False}),
    "pv-standard": ("probvis", {"photons": 20000, "verify": "off"}),
    "pv-shifted": ("probvis", {"photons": 20000, "verify": "off", "estimator": "shifted"}),
    "pv-power": ("probvis", {"photons": 20000, "verify": "off", "estimator": "power", "power": 4}),
    "pv-adaptive": ("probvis", {"photons": 20000, "verify": "off", "estimator": "adaptive"}),
    "pv-levels": ("probvis", {"photons": 20000, "verify": "off", "levels": 2, "grouping": "count"}),
    "pv-cells": ("probvis", {"photons": 20000, "verify": "off", "cells": 2, "grouping": "random"}),
}


def digest(result):
    """Hash of the image, every AOV and the ray and test totals."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(result.image).tobytes())
    for k in sorted(result.aovs):
        h.update(k.encode())
        h.update(np.ascontiguousarray(result.aovs[k]).tobytes())
    s = result.stats
    h.update(json.dumps([s["shadow_rays"], s["intersection_tests"], s["negative_estimates"]]).encode())
    return h.hexdigest()[:32]


def render_digest(scene, label, res=24):
    vis, opts = CONFIGS[label]
    return digest(probvis.render(scene, spp=2, shadow_rays=3, seed=5, visibility=vis, visibility_options=opts,
                                 defines={"res": res}))


@pytest.mark.parametrize("scene", SCENES)
def test_renders_match_stored_hashes(scene):
    stored = json.loads(STORED.read_text())
    got = {label: render_digest(scene, label) for label in CONFIGS}
    differ = [label for label in CONFIGS if got[label] != stored[f"{scene}/{label}"]]
    assert not differ, f"{scene}: images, AOVs or counts changed for {differ}"


if __name__ == "__main__" and sys.argv[1:] == ["--store"]:
    STORED.write_text(json.dumps({f"{s}/{c}": render_digest(s, c) for s in SCENES for c in CONFIGS}, indent=1,
                                 sort_keys=True) + "\n")
