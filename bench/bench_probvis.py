"""Probabilistic-visibility benchmark, run by hand:
`python3 bench/bench_probvis.py [--shadow-rays 1,4,16,64,256] [--runs 1]`.

For ../shared/scenes city, leaves and cornell-bunny at 128x128, 16 spp: the occlusion map without probvis
(candidate lists, `penumbra=list`) against probvis with each estimator on the same lists, at each shadow-ray
count: render seconds (JIT excluded), ray-triangle tests and their change, relMSE against the reference, and
efficiency = 1 / (relMSE x seconds), also relative to the baseline. The same study with image strips,
plots and an interactive report: `probvis experiment experiments/paper.toml`.
"""
import argparse
import json
import statistics
from pathlib import Path

import numpy as np

import probvis
from probvis.io import read_exr

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
METHODS = {
    "om-list": ("occlusion-map", {"penumbra": "list"}),
    "standard": ("probvis", {"estimator": "standard"}),
    "shifted": ("probvis", {"estimator": "shifted"}),
    "power": ("probvis", {"estimator": "power"}),
    "adaptive": ("probvis", {"estimator": "adaptive"}),
}


def relmse(x, ref):
    return float(np.mean((x - ref) ** 2 / (ref ** 2 + 0.01)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="city,leaves,cornell-bunny")
    ap.add_argument("--shadow-rays", default="1,4,16,64,256")
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--json")
    args = ap.parse_args()
    probvis.render("quad-shadow", resolution=(8, 8), visibility="probvis")
    results = []
    for scene in args.scenes.split(","):
        path = SHARED / "scenes" / f"{scene}.xml"
        ref = read_exr(SHARED / "reference" / f"{scene}-128.exr")[..., :3]
        print(f"\n{scene}")
        print(f"{'method':<10}{'rays':>5}{'seconds':>9}{'tri tests':>14}{'Δtests':>8}{'neg':>7}{'relMSE':>10}"
              f"{'effic.':>9}{'×base':>7}")
        for sr in (int(x) for x in args.shadow_rays.split(",")):
            base = None
            for method in args.methods.split(","):
                vis, opts = METHODS[method]
                runs = [probvis.render(path, spp=16, shadow_rays=sr, seed=seed, defines={"res": 128}, visibility=vis,
                                       visibility_options=opts) for seed in range(args.runs)]
                sec = statistics.median(r.stats["seconds"]["total"] - r.stats["seconds"]["compile"] for r in runs)
                tri = statistics.median(r.stats["intersection_tests"]["shadow"]["triangle"] for r in runs)
                err = float(np.mean([relmse(r.image, ref) for r in runs]))
                eff = 1.0 / (err * sec)
                if base is None:
                    base = dict(tri=tri, eff=eff)
                neg = float(np.mean([r.stats["negative_estimate_share"] for r in runs]))
                row = dict(scene=scene, method=method, shadow_rays=sr, seconds=sec, triangle_tests=tri,
                           tests_change=tri / base["tri"] - 1, negative_share=neg, relmse=err, efficiency=eff,
                           efficiency_vs_baseline=eff / base["eff"])
                results.append(row)
                print(f"{method:<10}{sr:>5}{sec:9.2f}{tri:14,.0f}{row['tests_change']:8.1%}{neg:7.1%}{err:10.5f}"
                      f"{eff:9.1f}{row['efficiency_vs_baseline']:7.2f}", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
