"""Batch size of the kernel render paths, interleaved in one process, run by hand:

    python3 bench/bench_batches.py --scenes cornell-bunny city --lookups 12 14 15 16 --rounds 3

A kernel path (fused exact visibility, the occlusion map's and probvis's own kernels) takes at least
2^TARGET_LOOKUPS (camera sample, emitter) pairs per batch (`integrator.batch_pixels`); this patches that bound and
renders each shared scene at 256x256, 4 spp x 64 shadow rays, with the occlusion map's lists, probvis and exact
visibility (unverified, the 2013 conditions), the bounds and methods alternating round by round. Reported per
scene, bound and method: the median over rounds of seconds (prepare + render) and of the look-up phase.
"""
import argparse
import statistics
from pathlib import Path

import probvis
import probvis.integrator

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
METHODS = {"om-list": ("occlusion-map", {"penumbra": "list", "verify": "off"}),
           "probvis": ("probvis", {"verify": "off"}),
           "exact": ("exact", {})}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["cornell-bunny", "city", "leaves"])
    ap.add_argument("--lookups", type=int, nargs="+", default=[12, 14, 15, 16], help="log2 of the bound")
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--shadow-rays", type=int, default=64)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    print(f"256x256, {args.spp} spp x {args.shadow_rays} shadow rays, {args.rounds} rounds interleaved")
    for name in args.scenes:
        scene = probvis.load_scene(SHARED / "scenes" / f"{name}.xml", res=256)
        for vis, opts in METHODS.values():
            probvis.render(scene, spp=1, shadow_rays=1, visibility=vis, visibility_options=opts)
        runs = {}
        for _ in range(args.rounds):
            for bound in args.lookups:
                probvis.integrator.TARGET_LOOKUPS = 1 << bound
                for label, (vis, opts) in METHODS.items():
                    r = probvis.render(scene, spp=args.spp, shadow_rays=args.shadow_rays, seed=1, visibility=vis,
                                       visibility_options=opts)
                    s, est = r.stats["seconds"], r.stats.get("estimator", {}).get("seconds", {})
                    runs.setdefault((bound, label), []).append((s["prepare"] + s["render"], est.get("lookup", 0.0)))
        for (bound, label), v in runs.items():
            print(f"{name:14s} 2^{bound:<3d} {label:8s} {statistics.median(x[0] for x in v):6.3f} s   "
                  f"lookup {statistics.median(x[1] for x in v):6.3f} s", flush=True)


if __name__ == "__main__":
    main()
