"""Renderer-core benchmark, run by hand: `python3 bench/bench_core.py [--runs 5]`.

1. cornell-bunny at 256x256, 16 spp x 16 shadow rays, exact visibility: probvis and Mitsuba 3 alternately
   in this process (Mitsuba `llvm_ad_rgb`, else `scalar_rgb`, said so); median seconds (scene load + render,
   JIT compile excluded and reported apart), their ratio, shadow rays per second.
2. BVH build time for the bunny and for a generated 1M-triangle mesh (compile excluded, reported apart).
3. relMSE against ../shared/reference/*-128.exr at 16 spp x 16 shadow rays next to the floors.
"""
import argparse
import json
import os
import statistics
import time
from pathlib import Path

import numpy as np

import probvis
from probvis.accel import build_bvh
from probvis.io import read_exr

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


def relmse(x, ref):
    return float(np.mean((x - ref) ** 2 / (ref ** 2 + 0.01)))


def load_mitsuba():
    import mitsuba as mi

    if "DRJIT_LIBLLVM_PATH" not in os.environ:
        for cand in ("/usr/lib/x86_64-linux-gnu/libLLVM-19.so", "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"):
            if Path(cand).exists():
                os.environ["DRJIT_LIBLLVM_PATH"] = cand
    try:
        mi.set_variant("llvm_ad_rgb")
        variant = "llvm_ad_rgb"
    except Exception as exc:  # no libLLVM >= 16
        print(f"Mitsuba llvm_ad_rgb unavailable ({exc}); falling back to scalar_rgb")
        mi.set_variant("scalar_rgb")
        variant = "scalar_rgb"
    return mi, variant


def time_mitsuba(mi, path, seed, **params):
    t0 = time.perf_counter()
    scene = mi.load_file(str(path), **params)
    img = mi.render(scene, seed=seed)
    arr = np.array(img)
    return time.perf_counter() - t0, arr


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--json", help="also write the results here")
    args = ap.parse_args()
    scene_path = SHARED / "scenes" / "cornell-bunny.xml"
    if not scene_path.exists():
        raise SystemExit(f"{scene_path} not found: the benchmark needs ../shared")
    out = {}

    mi, variant = load_mitsuba()
    t0 = time.perf_counter()
    time_mitsuba(mi, scene_path, 0, res=args.res)  # Mitsuba's JIT warm-up
    mitsuba_warmup = time.perf_counter() - t0
    first = probvis.render(scene_path, seed=0, defines={"res": args.res})
    ours, theirs, rays = [], [], []
    for run in range(args.runs):
        t = time_mitsuba(mi, scene_path, run + 1, res=args.res)[0]
        theirs.append(t)
        r = probvis.render(scene_path, seed=run + 1, defines={"res": args.res})
        ours.append(sum(r.stats["seconds"][k] for k in ("load", "bvh", "prepare", "render")))
        rays.append(r.stats["shadow_rays_per_second"])
        print(f"run {run}: probvis {ours[-1]:.2f} s (render {r.stats['seconds']['render']:.2f}), "
              f"mitsuba {variant} {t:.2f} s")
    out["render"] = {
        "scene": "cornell-bunny", "res": args.res, "spp": 16, "shadow_rays": 16, "runs": args.runs,
        "probvis_median_s": statistics.median(ours), "mitsuba_median_s": statistics.median(theirs),
        "ratio": statistics.median(ours) / statistics.median(theirs), "mitsuba_variant": variant,
        "probvis_compile_s": first.stats["seconds"]["compile"], "mitsuba_first_run_s": mitsuba_warmup,
        "shadow_rays_per_second": statistics.median(rays),
    }
    print(f"\ncornell-bunny {args.res}^2, 16 spp x 16 shadow rays (median of {args.runs}, load+build+render):")
    print(f"  probvis {out['render']['probvis_median_s']:.2f} s, Mitsuba {variant} "
          f"{out['render']['mitsuba_median_s']:.2f} s, ratio {out['render']['ratio']:.2f}x; "
          f"{out['render']['shadow_rays_per_second'] / 1e6:.2f} M shadow rays/s")
    print(f"  first-call compile: probvis {first.stats['seconds']['compile']:.2f} s (numba cache), "
          f"Mitsuba first run {mitsuba_warmup:.2f} s")

    bunny = probvis.load_scene(scene_path)
    t0 = time.perf_counter()
    build_bvh(bunny.triangles[:64])  # compile (or load from cache)
    compile_s = time.perf_counter() - t0
    rng = np.random.default_rng(1)
    grid = 708  # 2 * 707^2 ~ 1M triangles: a bumpy height field
    x, y = np.meshgrid(np.linspace(-1, 1, grid), np.linspace(-1, 1, grid))
    z = 0.1 * np.sin(8 * x) * np.cos(6 * y) + 0.01 * rng.normal(size=x.shape)
    v = np.stack([x, y, z], -1)
    a, b, c, d = v[:-1, :-1], v[1:, :-1], v[1:, 1:], v[:-1, 1:]
    big = np.concatenate([np.stack([a, b, c], -2).reshape(-1, 3, 3), np.stack([a, c, d], -2).reshape(-1, 3, 3)])
    builds = {}
    for name, tris in (("bunny", bunny.triangles), ("grid-1M", big)):
        times = [build_bvh(tris).build_seconds for _ in range(3)]
        builds[name] = {"triangles": len(tris), "median_s": statistics.median(times)}
        print(f"BVH build {name}: {len(tris):,} triangles, {statistics.median(times):.3f} s (median of 3)")
    builds["compile_s"] = compile_s
    out["bvh"] = builds

    floors = json.loads((SHARED / "reference" / "floors.json").read_text())
    out["reference"] = {}
    print("\nrelMSE against the Mitsuba references (128 px, 16 spp x 16 shadow rays, mean of 3 seeds):")
    for name in ("cornell-bunny", "city", "leaves"):
        ref = read_exr(SHARED / "reference" / f"{name}-128.exr").astype(np.float64)
        errs = [relmse(probvis.render(SHARED / "scenes" / f"{name}.xml", spp=16, shadow_rays=16, seed=s,
                                      defines={"res": 128}).image, ref) for s in (1, 2, 3)]
        floor = float(np.mean(floors[name]["relmse_16spp_16sr"]))
        out["reference"][name] = {"relmse": float(np.mean(errs)), "floor": floor,
                                  "ratio": float(np.mean(errs)) / floor}
        print(f"  {name:<14} relMSE {np.mean(errs):.5f}  floor {floor:.5f}  ratio {np.mean(errs) / floor:.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
