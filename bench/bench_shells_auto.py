"""Exact visibility's shells settings side by side, run by hand:

    python3 bench/bench_shells_auto.py [--scenes ...] [--settings 4x16 4x64 16x16] [--seeds 3] [--res 256]

Shells change no pixel (tested bit for bit), so exact visibility's efficiency under each setting is the ratio
of its seconds: per scene and spp x shadow-rays setting, `--shells off`, `auto` (the default) and `on` render
with the same seeds, alternating within each seed. Seconds are the render phase plus the estimator's own
preparation (shells from the on-disk cache: a first build is made, and timed, before the timed renders), not
JIT compilation, scene loading or the scene BVH. Reported: medians over seeds, their ratio to `off`, and what
`auto` chose (the meshes it gave shells).
"""
import argparse
import statistics
import time

import probvis

SETTINGS = ("off", "auto", "on")


def seconds(stats):
    return stats["seconds"]["render"] + stats["seconds"]["prepare"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["heavy-scan", "heavy-open-scan", "heavy-small", "heavy-canopy"])
    ap.add_argument("--settings", nargs="+", default=["4x16", "4x64", "16x16"], help="spp x shadow rays")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--res", type=int, default=256)
    args = ap.parse_args()
    print(f"probvis {probvis.__version__}; {args.res}x{args.res}; seconds = render + estimator preparation, "
          f"median of {args.seeds} seeds; ratio = off's seconds / the setting's (efficiency x exact without shells)")
    for name in args.scenes:
        scene = probvis.load_scene(name, res=args.res)
        print(f"\n{name}: {scene.n_triangles:,} triangles", flush=True)
        for shells in SETTINGS:  # compile, build and cache the shells outside the timed renders
            t0 = time.perf_counter()
            r = probvis.render(scene, spp=1, shadow_rays=1, resolution=(8, 8), visibility_options={"shells": shells})
            chosen = [m["name"] + (" (closed)" if m["closed"] else "") for m in
                      (r.stats["estimator"].get("shells") or {}).get("meshes", [])]
            print(f"  {shells:4s}: shells for {chosen or 'no mesh'}; first render {time.perf_counter() - t0:.2f} s "
                  f"(prepare {r.stats['seconds']['prepare']:.2f} s)", flush=True)
        for setting in args.settings:
            spp, rays = (int(x) for x in setting.split("x"))
            times = {s: [] for s in SETTINGS}
            for seed in range(args.seeds):
                for shells in SETTINGS:
                    r = probvis.render(scene, spp=spp, shadow_rays=rays, seed=seed,
                                       visibility_options={"shells": shells})
                    times[shells].append(seconds(r.stats))
            base = statistics.median(times["off"])
            cells = "  ".join(f"{s} {statistics.median(times[s]):6.2f} s ({base / statistics.median(times[s]):.2f}x)"
                              for s in SETTINGS)
            print(f"  {setting:6s} {cells}", flush=True)


if __name__ == "__main__":
    main()
