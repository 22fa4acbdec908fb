"""Render speed of two probvis source trees, alternating in one run, run by hand:

    git worktree add /tmp/before <commit>
    python3 bench/bench_versions.py /tmp/before/src src --pairs 6

Each pair renders cornell-bunny (../shared; `--scene` for another) at 256x256, 16 spp x 16 shadow rays, exact visibility, three times
in a fresh process per tree (the trees alternate, first one then the other, so both see the machine's slow and
fast phases alike). Reported: per tree the median over pairs of each process's best render seconds (the
render phase, compile and loading excluded), and the median of the per-pair ratios second / first.
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
DRIVER = """
import inspect, json, sys
import probvis
import probvis.integrator
path, res, repeats, visibility = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
new_api = "defines" in inspect.signature(probvis.integrator.render).parameters
times = []
for seed in range(repeats):
    kw = {"defines": {"res": res}} if new_api else {"res": res}
    r = probvis.render(path, seed=seed, visibility=visibility, **kw)
    times.append(r.stats["seconds"]["render"])
print(json.dumps({"render": times, "image_mean": r.stats["image_mean"], "tests": r.stats["intersection_tests"]}))
"""


def run(src, scene, res, repeats, visibility):
    env = dict(os.environ, PYTHONPATH=str(Path(src).resolve()))
    out = subprocess.run([sys.executable, "-c", DRIVER, str(scene), str(res),
                          str(repeats), visibility], capture_output=True, text=True, env=env, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("first", help="src folder of the first tree (e.g. the commit before a change)")
    ap.add_argument("second", help="src folder of the second tree")
    ap.add_argument("--pairs", type=int, default=6)
    ap.add_argument("--repeats", type=int, default=3, help="renders per process (the best counts)")
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--visibility", default="exact")
    ap.add_argument("--scene", default="cornell-bunny", help="a scene of ../shared/scenes (default cornell-bunny)")
    args = ap.parse_args()
    scene = SHARED / "scenes" / f"{args.scene}.xml"
    for src in (args.first, args.second):  # compile both outside the timing
        run(src, scene, 8, 1, args.visibility)
    first, second, ratios = [], [], []
    for k in range(args.pairs):
        a = run(args.first, scene, args.res, args.repeats, args.visibility)
        b = run(args.second, scene, args.res, args.repeats, args.visibility)
        first.append(min(a["render"]))
        second.append(min(b["render"]))
        ratios.append(second[-1] / first[-1])
        same = a["image_mean"] == b["image_mean"] and a["tests"] == b["tests"]
        print(f"pair {k}: {first[-1]:.3f} s vs {second[-1]:.3f} s, ratio {ratios[-1]:.3f}"
              f"{'' if same else '  (images or test counts differ)'}", flush=True)
    print(f"median render seconds: first {statistics.median(first):.3f}, second {statistics.median(second):.3f}; "
          f"median ratio second/first {statistics.median(ratios):.3f} over {args.pairs} pairs")


if __name__ == "__main__":
    main()
