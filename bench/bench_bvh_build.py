"""BVH build time on the heavy built-ins, run by hand:
`python3 bench/bench_bvh_build.py [--scenes heavy-scan heavy-open-scan heavy-canopy] [--rounds 7] [--against SRC]`.

Builds the scene BVH (`accel.build_bvh`) of each scene's triangles `--rounds` times in a fresh process per tree
(compilation excluded: one warm-up build first) and prints the median and fastest seconds, the node count and a
digest of the tree (bounds, node links, primitive order). With `--against SRC` (another checkout's `src`
folder, e.g. `git worktree add /tmp/before HEAD~1` then `/tmp/before/src`) the two trees alternate round by
round and the ratio of medians is printed, with whether the two builds made the same tree node for node.
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parents[1] / "src"

WORKER = """
import hashlib, json, sys, time
import numpy as np
import probvis
from probvis.accel import build_bvh
tris = np.ascontiguousarray(probvis.load_scene(sys.argv[1], res=16).triangles)
bvh = build_bvh(tris)
times = []
for _ in range(int(sys.argv[2])):
    t0 = time.perf_counter()
    bvh = build_bvh(tris)
    times.append(time.perf_counter() - t0)
h = hashlib.sha256()
for a in (bvh.bounds, bvh.node_index, bvh.node_count, bvh.prim_ids):
    h.update(np.ascontiguousarray(a).tobytes())
print(json.dumps({"triangles": len(tris), "nodes": len(bvh.node_count), "times": times,
                  "digest": h.hexdigest()[:16], "file": probvis.__file__}))
"""


def run(src, scene, rounds):
    env = dict(os.environ, PYTHONPATH=str(src))
    out = subprocess.run([sys.executable, "-c", WORKER, scene, str(rounds)], env=env, check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["heavy-scan", "heavy-open-scan", "heavy-canopy"])
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--against", metavar="SRC", help="another checkout's src folder to compare with")
    args = ap.parse_args()
    trees = [("this", HERE)] + ([("against", Path(args.against).resolve())] if args.against else [])
    print(f"threads: {os.environ.get('NUMBA_NUM_THREADS', os.cpu_count())}, rounds {args.rounds} per process, "
          f"processes alternate")
    for scene in args.scenes:
        got = {name: [] for name, _ in trees}
        facts = {}
        for _ in range(2):  # two processes per tree, alternating
            for name, src in trees:
                r = run(src, scene, args.rounds)
                got[name] += r["times"]
                facts[name] = r
        line = [f"{scene}: {facts['this']['triangles']:,} triangles"]
        for name, _ in trees:
            f = facts[name]
            line.append(f"{name} median {statistics.median(got[name]):.3f} s, min {min(got[name]):.3f} s, "
                        f"{f['nodes']:,} nodes, digest {f['digest']}")
        if args.against:
            ratio = statistics.median(got["this"]) / statistics.median(got["against"])
            same = facts["this"]["digest"] == facts["against"]["digest"]
            line.append(f"ratio this/against {ratio:.2f}, {'the same tree' if same else 'a different tree'}")
        print("; ".join(line), flush=True)


if __name__ == "__main__":
    main()
