"""What the automatic choices cost, interleaved, run by hand:
`python3 bench/bench_auto_cost.py [--scenes heavy-small cornell-bunny city leaves] [--seeds 4]`.

Exact visibility without shells (the baseline), exact visibility's default (`--shells auto`: a survey, then
shells only where they are predicted to pay) and `proxy` with its efficiency-aware q (the survey, then a pilot
only where it fits in 3% of the render), deciding afresh (its cached decisions removed first: a first render)
and with the decision cached (a render of the same scene again), on the same scene in one process, in the
order A B C D D C B A for each seed, at 4 spp x 16 and 64 shadow rays and 16 spp x 16. Seconds = the
estimator's preparation + the render (not the scene load and BVH every method shares), median over the seeds'
two renders each; the ratio is the baseline's seconds over the method's (its efficiency where the images are
the same, which is said). Built-ins at 256x256, shared scenes (with ../shared beside the repository) at 128x128
as in experiments/proxies.toml.
"""
import argparse
import shutil
import statistics
from pathlib import Path

import numpy as np

import probvis
from probvis.disk_cache import cache_dir

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
METHODS = [("exact, no shells", "exact", {"shells": "off"}), ("exact default", "exact", {}),
           ("proxy auto, deciding", "proxy", {}), ("proxy auto, decided", "proxy", {})]
SETTINGS = [(4, 16), (4, 64), (16, 16)]


def load(name):
    if name in probvis.BUILTINS:
        return probvis.load_scene(name, res=256)
    return probvis.load_scene(SHARED / "scenes" / f"{name}.xml", res=128)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["heavy-small", "cornell-bunny", "city", "leaves"])
    ap.add_argument("--seeds", type=int, default=4)
    args = ap.parse_args()
    for name in args.scenes:
        scene = load(name)
        for _, vis, opts in METHODS:  # compile and fill the proxy and shell caches, untimed
            probvis.render(scene, spp=1, shadow_rays=1, visibility=vis, visibility_options=opts)
        for spp, rays in SETTINGS:
            seconds = {m[0]: [] for m in METHODS}
            same = {m[0]: True for m in METHODS}
            for seed in range(args.seeds):
                images = {}
                for label, vis, opts in METHODS + METHODS[::-1]:
                    if label.endswith("deciding"):
                        shutil.rmtree(cache_dir("plans"), ignore_errors=True)
                    r = probvis.render(scene, spp=spp, shadow_rays=rays, seed=seed, visibility=vis,
                                       visibility_options=opts)
                    seconds[label].append(r.stats["seconds"]["prepare"] + r.stats["seconds"]["render"])
                    images.setdefault(label, r.image)
                for label in images:
                    same[label] &= bool(np.array_equal(images[label], images[METHODS[0][0]]))
            base = statistics.median(seconds[METHODS[0][0]])
            cells = [f"{label} {statistics.median(s):.3f} s ({base / statistics.median(s):.2f}x"
                     f"{', same image' if same[label] and label != METHODS[0][0] else ''})"
                     for label, s in seconds.items()]
            print(f"{name} {spp}x{rays}: " + "; ".join(cells), flush=True)


if __name__ == "__main__":
    main()
