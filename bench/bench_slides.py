"""The 2013 slides' comparison, interleaved: the occlusion map's candidate lists without and with probabilistic
visibility, unverified (the paper's conditions) and verified (the defaults), on the shared scenes. Run by hand:

    python3 bench/bench_slides.py --res 256 --spp 4 --shadow-rays 64 --seeds 1 2 --rounds 3

Per round and seed the methods render one after the other in one process (so they see the machine's slow and
fast phases alike); reported per scene and method: the median over rounds and seeds of seconds (prepare +
render, the estimator's photons and map included, scene loading and BVH not), and of shadow-ray triangle tests,
with both as ratios of the lists' (verified methods against the verified lists), and the seconds of the
kernel's phases (`stats["estimator"]["seconds"]`).
"""
import argparse
import statistics
from pathlib import Path

import probvis

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
METHODS = {
    "om-list off": ("occlusion-map", {"penumbra": "list", "verify": "off"}),
    "standard off": ("probvis", {"verify": "off"}),
    "shifted off": ("probvis", {"estimator": "shifted", "verify": "off"}),
    "om-list": ("occlusion-map", {"penumbra": "list"}),
    "standard": ("probvis", {}),
    "shifted": ("probvis", {"estimator": "shifted"}),
}
PHASES = ("lookup", "grouping", "sampling", "term_choice", "candidate_tests", "exact_traces", "verification_traces")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["city", "leaves", "cornell-bunny"])
    ap.add_argument("--methods", nargs="+", default=list(METHODS))
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--shadow-rays", type=int, default=64)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    print(f"{args.res}x{args.res}, {args.spp} spp x {args.shadow_rays} shadow rays, seeds {args.seeds}, "
          f"{args.rounds} rounds interleaved")
    for name in args.scenes:
        scene = probvis.load_scene(SHARED / "scenes" / f"{name}.xml", res=args.res)
        for label in args.methods:  # compile and warm every kernel outside the timing
            vis, opts = METHODS[label]
            probvis.render(scene, spp=1, shadow_rays=1, visibility=vis, visibility_options=opts)
        runs = {label: [] for label in args.methods}
        for _ in range(args.rounds):
            for seed in args.seeds:
                for label in args.methods:
                    vis, opts = METHODS[label]
                    r = probvis.render(scene, spp=args.spp, shadow_rays=args.shadow_rays, seed=seed, visibility=vis,
                                       visibility_options=opts)
                    runs[label].append(r.stats)
        med = {}
        for label, stats in runs.items():
            sec = statistics.median(s["seconds"]["prepare"] + s["seconds"]["render"] for s in stats)
            tests = statistics.median(s["intersection_tests"]["shadow"]["triangle"] for s in stats)
            phases = {p: statistics.median(s["estimator"]["seconds"].get(p, 0.0) for s in stats) for p in PHASES}
            med[label] = (sec, tests, phases)
        for label, (sec, tests, phases) in med.items():
            base = med.get("om-list off" if label.endswith("off") else "om-list")
            ratio = f"{sec / base[0]:.2f}x s, {tests / base[1]:.2f}x tests" if base else ""
            split = " ".join(f"{p} {v:.2f}" for p, v in phases.items() if v >= 0.005)
            print(f"{name:14s} {label:13s} {sec:6.2f} s {tests / 1e6:8.1f}M tests  {ratio:24s} | {split}",
                  flush=True)


if __name__ == "__main__":
    main()
