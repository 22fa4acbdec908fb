"""Render time on a busy machine, run by hand: `python3 bench/bench_contention.py [--pairs 3]`.

For each threading configuration (Numba's OpenMP layer as libgomp starts, with OMP_WAIT_POLICY=passive, with
short spin counts - probvis sets GOMP_SPINCOUNT=1000 unless the environment has one - and Numba's
workqueue layer), renders run in fresh processes, alternately on the idle machine and with two busy processes
(pure-Python spin loops, one per core) started and stopped around them, so both see the machine's phases
alike. Reported per configuration and render: the median idle and busy seconds (render phase) and their ratio;
a fair share of 2 cores among 3 busy processes is a ratio of about 2.
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import time

RENDERS = {
    "exact cornell-box 128": ["cornell-box", "-D", "res=128", "-D", "spp=16", "-D", "shadow_rays=16"],
    "probvis canopy 128": ["canopy", "-D", "res=128", "-D", "spp=4", "-D", "shadow_rays=16", "--visibility", "probvis",
                           "--estimator", "shifted"],
}
CONFIGS = {
    "omp, libgomp's default spin": {"GOMP_SPINCOUNT": "300000", "OMP_WAIT_POLICY": ""},
    "omp, OMP_WAIT_POLICY=passive": {"OMP_WAIT_POLICY": "passive", "GOMP_SPINCOUNT": "0"},
    "omp, GOMP_SPINCOUNT=1000 (probvis's)": {"GOMP_SPINCOUNT": "1000", "OMP_WAIT_POLICY": ""},
    "omp, GOMP_SPINCOUNT=10000": {"GOMP_SPINCOUNT": "10000", "OMP_WAIT_POLICY": ""},
    "workqueue": {"NUMBA_THREADING_LAYER": "workqueue", "GOMP_SPINCOUNT": "", "OMP_WAIT_POLICY": ""},
}
SPIN = "import time\nt = time.time()\nwhile time.time() - t < 600: pass"


def render_seconds(args, env):
    stats = f"/tmp/bench-contention-{os.getpid()}.json"
    subprocess.run([sys.executable, "-m", "probvis.cli", "render", *args, "-o", "/tmp/bench-contention.exr",
                    "--stats", stats, "-q"], env=env, check=True)
    with open(stats) as f:
        return json.load(f)["seconds"]["render"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=3)
    args = ap.parse_args()
    for cname, extra in CONFIGS.items():
        env = {k: v for k, v in dict(os.environ, **extra).items() if v != ""}  # "" unsets
        for rname, rargs in RENDERS.items():
            render_seconds(rargs, env)  # warm the kernel cache
            idle, busy = [], []
            for _ in range(args.pairs):
                idle.append(render_seconds(rargs, env))
                spinners = [subprocess.Popen([sys.executable, "-c", SPIN]) for _ in range(2)]
                time.sleep(0.5)
                try:
                    busy.append(render_seconds(rargs, env))
                finally:
                    for p in spinners:
                        p.kill()
                        p.wait()
            i, b = statistics.median(idle), statistics.median(busy)
            print(f"{cname:<30} {rname:<22} idle {i:6.2f} s  busy {b:6.2f} s  ratio {b / i:5.2f}", flush=True)


if __name__ == "__main__":
    main()
