"""Whole processes against Mitsuba 3's command line, run by hand:
`python3 bench/bench_turnaround.py [--scenes cornell-bunny city leaves] [--runs 5]`.

For each shared scene at its defaults (256x256, the file's samples), `probvis render SCENE -o out.exr` and
`mitsuba -m llvm_ad_rgb SCENE -o out.exr` alternate as child processes, caches warm (one untimed run of each
first: Python's bytecode, Numba's and Dr.Jit's kernel caches, the OS's file cache). Per process: wall seconds
and peak resident memory (the child's own, from `wait4`); for probvis also its phases from `--stats`. Medians
over the runs and their ratio. Mitsuba's llvm variant needs libLLVM >= 16 (Debian's libllvm19): DRJIT_LIBLLVM_PATH is set to it
when found. Needs ../shared beside the repository.
"""
import argparse
import json
import os
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
LLVM = ("/usr/lib/x86_64-linux-gnu/libLLVM-19.so", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1",
        "/usr/lib/llvm-19/lib/libLLVM.so.1", "/usr/lib/llvm-19/lib/libLLVM-19.so")


def run(cmd, env):
    """Wall seconds and peak RSS (MiB) of one child process; its exit must be 0."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read().decode(errors="replace")
    proc.stderr.close()
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} exited {proc.returncode}:\n{err[-2000:]}")
    return wall, usage.ru_maxrss / 1024


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["cornell-bunny", "city", "leaves"])
    ap.add_argument("--runs", type=int, default=5)
    args = ap.parse_args()
    env = dict(os.environ)
    # Python's bytecode cache is one of the warm caches: `pip install` writes it, so an installed probvis never
    # compiles its modules at start; a checkout under PYTHONDONTWRITEBYTECODE would, 0.1 s per process
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    if "DRJIT_LIBLLVM_PATH" not in env:
        env.update({"DRJIT_LIBLLVM_PATH": p for p in LLVM if Path(p).exists()})
    tmp = Path(tempfile.mkdtemp(prefix="turnaround-"))
    probvis = ["probvis", "render"]
    print(f"# python3 bench/bench_turnaround.py --scenes {' '.join(args.scenes)} --runs {args.runs}; "
          f"{os.cpu_count()} cores; DRJIT_LIBLLVM_PATH={env.get('DRJIT_LIBLLVM_PATH')}")
    for name in args.scenes:
        xml = SHARED / "scenes" / f"{name}.xml"
        if not xml.exists():
            raise SystemExit(f"{xml} not found: the benchmark needs ../shared")
        stats = tmp / f"{name}.json"
        ours = probvis + [str(xml), "-o", str(tmp / f"{name}-probvis.exr"), "--stats", str(stats), "-q"]
        theirs = ["mitsuba", "-m", "llvm_ad_rgb", str(xml), "-o", str(tmp / f"{name}-mitsuba.exr")]
        run(ours, env), run(theirs, env)  # warm caches
        rows = {"probvis": [], "mitsuba": []}
        phases = []
        for _ in range(args.runs):
            rows["probvis"].append(run(ours, env))
            seconds = json.loads(stats.read_text())["seconds"]
            phases.append({k: seconds[k] for k in ("load", "compile", "bvh", "prepare", "render")})
            rows["mitsuba"].append(run(theirs, env))
        med = {k: (statistics.median(w for w, _ in v), statistics.median(m for _, m in v)) for k, v in rows.items()}
        phase = {k: statistics.median(p[k] for p in phases) for k in phases[0]}
        print(f"{name}: probvis {med['probvis'][0]:.2f} s, {med['probvis'][1]:.0f} MiB; "
              f"mitsuba {med['mitsuba'][0]:.2f} s, {med['mitsuba'][1]:.0f} MiB; "
              f"wall ratio {med['probvis'][0] / med['mitsuba'][0]:.2f}x (median of {args.runs}, interleaved)")
        print("  probvis phases: " + ", ".join(f"{k} {v:.3f} s" for k, v in phase.items())
              + f"; the rest of the process (interpreter, imports, writing) "
              f"{med['probvis'][0] - sum(phase.values()):.2f} s", flush=True)


if __name__ == "__main__":
    main()
