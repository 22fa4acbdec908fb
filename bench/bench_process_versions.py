"""Whole `probvis render` processes of two probvis source trees, alternating in one run, run by hand:

    git worktree add /tmp/before <commit>; git worktree add /tmp/head HEAD
    python3 bench/bench_process_versions.py /tmp/before/src /tmp/head/src [--rounds 7] [--scenes city]

What a command costs from start to exit (imports, scene loading, kernels from Numba's cache, render, writing), each
tree on PYTHONPATH in its own child process, `python3 -m probvis render SCENE -o out.exr -q` at the scene's
defaults. Two untimed runs per tree first (Python's bytecode and Numba's caches: PYTHONDONTWRITEBYTECODE is
dropped, as an installed probvis has its bytecode), then the trees alternate, first one then the other, the order
reversed every round. Reported per scene: each tree's median seconds and their ratio second / first. Keep both
trees in the same place (both under /tmp): a tree elsewhere measured a few percent apart. Needs ../shared.
"""
import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("first")
    ap.add_argument("second")
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--scenes", nargs="+", default=["cornell-bunny", "city", "leaves"])
    args = ap.parse_args()
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    trees = [args.first, args.second]
    out = Path(tempfile.mkdtemp(prefix="process-versions-"))

    def run(k, xml):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "probvis", "render", str(xml), "-o", str(out / f"{k}.exr"), "-q"],
                       env=dict(env, PYTHONPATH=trees[k]), check=True)
        return time.perf_counter() - t0

    print(f"# python3 bench/bench_process_versions.py {args.first} {args.second} --rounds {args.rounds} "
          f"--scenes {' '.join(args.scenes)}; {os.cpu_count()} cores")
    for name in args.scenes:
        xml = SHARED / "scenes" / f"{name}.xml"
        if not xml.exists():
            raise SystemExit(f"{xml} not found: the benchmark needs ../shared")
        for k in (0, 1, 0, 1):
            run(k, xml)
        times = ([], [])
        for r in range(args.rounds):
            for k in ((0, 1) if r % 2 == 0 else (1, 0)):
                times[k].append(run(k, xml))
        first, second = (statistics.median(t) for t in times)
        print(f"{name}: first {first:.3f} s, second {second:.3f} s, second/first {second / first:.3f} "
              f"(median of {args.rounds}, alternating)", flush=True)


if __name__ == "__main__":
    main()
