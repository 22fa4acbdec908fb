"""What a first run compiles, kernel by kernel, run by hand on an empty Numba cache:

    NUMBA_CACHE_DIR=$(mktemp -d) python3 bench/bench_compile.py --visibility exact occlusion-map probvis

Renders the built-in quad-shadow scene at 4x4 (what `probvis render` warms up with) once per estimator, in that
order, with Numba's compile events recorded (`numba.core.event`). Reported per estimator: the wall seconds of
its first render and of compilation, the kernels compiled (a kernel compiled again for new argument types
counts once more), and the slowest kernels by inclusive seconds (a kernel's time includes the callees compiled
for it). Run it again with the same NUMBA_CACHE_DIR to see the cache's load time instead.
"""
import argparse
import time
from collections import defaultdict

from numba.core import event


class Recorder(event.Listener):
    """Inclusive seconds per compiled function (outermost compiles only count towards the total)."""

    def __init__(self):
        self.stack, self.seconds, self.count, self.total = [], defaultdict(float), defaultdict(int), 0.0

    def on_start(self, ev):
        self.stack.append(time.perf_counter())

    def on_end(self, ev):
        dt = time.perf_counter() - self.stack.pop()
        disp = ev.data.get("dispatcher")
        name = getattr(getattr(disp, "py_func", None), "__qualname__", str(disp))
        module = getattr(getattr(disp, "py_func", None), "__module__", "")
        key = f"{module}.{name}"
        self.seconds[key] += dt
        self.count[key] += 1
        if not self.stack:
            self.total += dt


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--visibility", nargs="+", default=["exact", "occlusion-map", "probvis"])
    ap.add_argument("--top", type=int, default=12)
    args = ap.parse_args()
    t0 = time.perf_counter()
    import probvis
    from probvis.scene.builtin import quad_shadow

    print(f"import probvis: {time.perf_counter() - t0:.2f} s")
    scene = quad_shadow(res=4)
    for vis in args.visibility:
        rec = Recorder()
        t0 = time.perf_counter()
        with event.install_listener("numba:compile", rec):
            probvis.render(scene, spp=1, shadow_rays=2, visibility=vis)
        wall = time.perf_counter() - t0
        print(f"\n{vis}: first render {wall:.1f} s, compiling {rec.total:.1f} s, {sum(rec.count.values())} "
              f"compilations of {len(rec.count)} functions")
        for key, sec in sorted(rec.seconds.items(), key=lambda kv: -kv[1])[:args.top]:
            print(f"  {sec:6.1f} s  x{rec.count[key]}  {key}", flush=True)


if __name__ == "__main__":
    main()
