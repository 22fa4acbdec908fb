"""Occlusion-map benchmark, run by hand: `python3 bench/bench_occlusion_map.py [--runs 3]`.

For ../shared/scenes cornell-bunny, city and leaves at 128x128, 16 spp x 16 shadow rays: exact visibility
against the occlusion map with list and bvh penumbra (verified, the default, and unverified), with adaptive
photons, and probabilistic visibility (shifted) on the same lists. Per method: median seconds per phase over
`--runs` seeds, shadow rays, ray-triangle and ray-node tests (shadow rays plus photon pass), relMSE against
../shared/reference next to the Mitsuba noise floor, efficiency 1/(relMSE x seconds), the block-bias ratio of
the first two seeds (about 1: converges to the reference) and the share of the photon pass and map build in
the total time (JIT compile excluded).
"""
import argparse
import json
import statistics
from pathlib import Path

import numpy as np

import probvis
from probvis.experiments.metrics import block_bias_ratio
from probvis.io import read_exr

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
METHODS = {
    "exact": ("exact", {}),
    "om-list": ("occlusion-map", {"penumbra": "list"}),
    "om-bvh": ("occlusion-map", {"penumbra": "bvh"}),
    "om-bvh-adaptive": ("occlusion-map", {"penumbra": "bvh", "adaptive_photons": True}),
    "om-list-adaptive": ("occlusion-map", {"penumbra": "list", "adaptive_photons": True}),
    "om-list-unverified": ("occlusion-map", {"penumbra": "list", "verify": "off"}),
    "om-bvh-unverified": ("occlusion-map", {"penumbra": "bvh", "verify": "off"}),
    "shifted": ("probvis", {"estimator": "shifted"}),
    "shifted-unverified": ("probvis", {"estimator": "shifted", "verify": "off"}),
}


def relmse(x, ref):
    return float(np.mean((x - ref) ** 2 / (ref ** 2 + 0.01)))


def run(scene, method, seed):
    vis, opts = METHODS[method]
    r = probvis.render(SHARED / "scenes" / f"{scene}.xml", spp=16, shadow_rays=16, seed=seed, defines={"res": 128},
                       visibility=vis, visibility_options=opts)
    s = r.stats
    est = s["estimator"] or {}
    sec = est.get("seconds", {})
    photon = sec.get("photons", 0.0) + sec.get("adaptive_photons", 0.0) + sec.get("map_build", 0.0)
    pt = est.get("photon_tests", {"triangle": 0, "node": 0})
    return r.image, {
        "total": s["seconds"]["total"] - s["seconds"]["compile"], "build": s["seconds"]["bvh"] + s["seconds"]["prepare"],
        "render": s["seconds"]["render"], "photon_and_map": photon, "lookup": sec.get("lookup", 0.0),
        "shadow_rays": s["shadow_rays"],
        "triangle_tests": s["intersection_tests"]["shadow"]["triangle"] + pt["triangle"],
        "node_tests": s["intersection_tests"]["shadow"]["node"] + pt["node"],
        "list_mean": (est.get("list_length") or {}).get("mean"),
        "cases": {k: v["share"] for k, v in s["cases"].items()} if s["cases"] else None,
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3, help="seeds (at least 2 for the bias column)")
    ap.add_argument("--scenes", default="cornell-bunny,city,leaves")
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--json", help="also write the results here")
    args = ap.parse_args()
    floors = json.loads((SHARED / "reference" / "floors.json").read_text())
    probvis.render("quad-shadow", resolution=(8, 8), visibility="occlusion-map")  # compile outside the timing
    results = {}
    for scene in args.scenes.split(","):
        ref = read_exr(SHARED / "reference" / f"{scene}-128.exr")[..., :3]
        floor = float(np.mean(floors[scene]["relmse_16spp_16sr"]))
        print(f"\n{scene}: noise floor relMSE {floor:.5f}")
        print(f"{'method':<18}{'total s':>8}{'photon+map':>11}{'share':>7}{'lookup':>7}{'shadow rays':>12}"
              f"{'tri tests':>12}{'node tests':>12}{'list':>6}{'relMSE':>9}{'/floor':>7}{'effic.':>8}{'bias':>7}")
        for method in args.methods.split(","):
            runs = [run(scene, method, seed) for seed in range(args.runs)]
            med = {k: statistics.median(r[1][k] for r in runs) for k in
                   ("total", "photon_and_map", "lookup", "shadow_rays", "triangle_tests", "node_tests")}
            err = float(np.mean([relmse(img, ref) for img, _ in runs]))
            bias = (block_bias_ratio(runs[0][0], runs[1][0], ref, reference_noise=floor * 16 / 2048)
                    if len(runs) > 1 else float("nan"))
            row = dict(med, relmse=err, relmse_over_floor=err / floor, list_mean=runs[0][1]["list_mean"],
                       cases=runs[0][1]["cases"], photon_share=med["photon_and_map"] / med["total"],
                       efficiency=1 / (err * med["total"]), bias_ratio=bias)
            results.setdefault(scene, {})[method] = row
            lm = f"{row['list_mean']:.0f}" if row["list_mean"] else "-"
            print(f"{method:<18}{med['total']:8.2f}{med['photon_and_map']:11.2f}{row['photon_share']:7.0%}"
                  f"{med['lookup']:7.2f}{med['shadow_rays']:12,.0f}{med['triangle_tests']:12,.0f}"
                  f"{med['node_tests']:12,.0f}{lm:>6}{err:9.5f}{err / floor:7.2f}{row['efficiency']:8.1f}"
                  f"{bias:7.1f}", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
