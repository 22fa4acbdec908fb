"""Whole `probvis render` processes with and without NumPy's huge-page advice, interleaved, run by hand:

    python3 bench/bench_huge_pages.py [--rounds 3] [--scenes heavy-canopy heavy-scan city cornell-bunny]

NumPy advises huge pages for its large arrays unless NUMPY_MADVISE_HUGEPAGE=0 (docs/decisions.md); this runs the
command with 1 (NumPy's default advice) and 0 one after the other in each round and prints each process's wall
seconds, peak memory and phases (from --stats), then the medians. The shared scenes need ../shared beside the
repository.
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "scenes"
ARGS = {"heavy-canopy": ["heavy-canopy", "--spp", "4", "--shadow-rays", "64", "-D", "res=128"],
        "heavy-scan": ["heavy-scan"], "city": [str(SHARED / "city.xml")],
        "cornell-bunny": [str(SHARED / "cornell-bunny.xml")]}
PHASES = ("load", "compile", "bvh", "render")


def run(scene, advice, folder):
    """(wall seconds, peak MiB, phases) of one `probvis render` process."""
    stats = Path(folder) / "s.json"
    env = dict(os.environ, NUMPY_MADVISE_HUGEPAGE=advice)
    code = ("import resource, subprocess, sys, time; t = time.perf_counter(); "
            "subprocess.run(sys.argv[1:], check=True); "
            "print(time.perf_counter() - t, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)")
    out = subprocess.run([sys.executable, "-c", code, sys.executable, "-m", "probvis", "render", *ARGS[scene], "-q",
                          "-o", str(Path(folder) / "o.exr"), "--stats", str(stats)], env=env, capture_output=True,
                         text=True, check=True).stdout.split()
    sec = json.loads(stats.read_text())["seconds"]
    return float(out[0]), int(out[1]) / 1024, {p: sec[p] for p in PHASES}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--scenes", nargs="+", default=list(ARGS), choices=list(ARGS))
    args = ap.parse_args()
    walls = {(s, a): [] for s in args.scenes for a in "10"}
    with tempfile.TemporaryDirectory() as folder:
        for _ in range(args.rounds):
            for scene in args.scenes:
                for advice in "10":
                    wall, mib, sec = run(scene, advice, folder)
                    walls[scene, advice].append(wall)
                    print(f"{scene:14s} advice {advice}: {wall:5.2f} s, {mib:4.0f} MiB  "
                          + " ".join(f"{p} {sec[p]:.2f}" for p in PHASES), flush=True)
                    time.sleep(0.5)
    for scene in args.scenes:
        on, off = (statistics.median(walls[scene, a]) for a in "10")
        print(f"{scene}: median {on:.2f} s with the advice, {off:.2f} s without ({off / on:.2f}x)")


if __name__ == "__main__":
    main()
