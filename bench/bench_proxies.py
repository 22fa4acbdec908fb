"""Proxy visibility against exact visibility, side by side, run by hand:
`python3 bench/bench_proxies.py [--runs 2] [--res 256] [--spp 16] [--shadow-rays 16] [--scenes ...]`.

Per scene (the heavy built-ins, and the shared scenes when ../shared is beside the repository) and method
(exact; proxy with efficiency-aware q; proxy at fixed q; proxy with decimated meshes only), `--runs` seeds alternate between methods in this
process. Seconds are the render phase plus the estimator's own preparation (proxies come from the cache after
the first run, which is not timed), without JIT compile, scene loading and the scene BVH that every method
shares. relMSE is against a reference: the shared scenes' Mitsuba 3 renders, or for a built-in an exact render
at `--ref-spp` samples per pixel (made once and cached in --ref-dir). Efficiency = 1 / (relMSE x seconds), its
ratio to exact's in the same run; the block-bias ratio compares two seeds' block means (about 1 when unbiased).
"""
import argparse
import json
import statistics
import sys
import warnings
from pathlib import Path

import numpy as np

import probvis
from probvis.experiments.metrics import block_bias_ratio
from probvis.io import read_exr, write_exr

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
METHODS = [("exact", "exact", {}), ("exact shells", "exact", {"shells": True}), ("proxy auto", "proxy", {}),
           ("auto no shells", "proxy", {"shells": False}), ("proxy q=0.1", "proxy", {"q": "0.1"}),
           ("q=0.1 no shells", "proxy", {"shells": False, "q": "0.1"}), ("proxy q=0.5", "proxy", {"q": "0.5"}),
           ("proxy mesh", "proxy", {"kind": "mesh"}), ("mesh no shells", "proxy", {"kind": "mesh", "shells": False})]


def relmse(x, ref):
    return float(np.mean((x - ref) ** 2 / (ref ** 2 + 0.01)))


def scene_list(names, res):
    out = []
    for name in names:
        if name.startswith("shared:"):
            stem = name.split(":", 1)[1]
            if not (SHARED / "scenes").is_dir():
                print(f"{name}: ../shared not found, skipped")
                continue
            floors = json.loads((SHARED / "reference" / "floors.json").read_text())
            ref = read_exr(SHARED / "reference" / f"{stem}-128.exr").astype(np.float64)
            noise = float(np.mean(floors[stem]["relmse_16spp_16sr"])) * 16 / 2048
            out.append((stem, probvis.load_scene(SHARED / "scenes" / f"{stem}.xml", res=128), ref, noise))
        else:
            out.append((name, probvis.load_scene(name, res=res), None, 0.0))
    return out


def reference(name, scene, spp, folder):
    path = Path(folder) / f"{name}-{scene.camera.width}-exact-{spp}spp.exr"
    if not path.is_file():
        print(f"  reference: exact visibility at {spp} spp x 16 shadow rays -> {path}", flush=True)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_exr(path, probvis.render(scene, spp=spp, shadow_rays=16, seed=999).image)
    # its own noise: relMSE of a render at spp s is about floor x 16 / s; measured below per scene
    return read_exr(path).astype(np.float64)


def seconds(stats):
    s = stats["seconds"]
    return s["render"] + s["prepare"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--shadow-rays", type=int, default=16)
    ap.add_argument("--ref-spp", type=int, default=256)
    ap.add_argument("--ref-dir", default=str(Path.home() / ".cache" / "probvis" / "bench-references"))
    ap.add_argument("--scenes", nargs="+", default=["heavy-scan", "heavy-canopy", "shared:cornell-bunny",
                                                     "shared:city", "shared:leaves"])
    ap.add_argument("--methods", nargs="+", default=[m[0] for m in METHODS], help="labels of METHODS to run")
    args = ap.parse_args()
    methods = [m for m in METHODS if m[0] in args.methods]
    warnings.simplefilter("ignore")
    print(f"probvis {probvis.__version__}; {args.spp} spp x {args.shadow_rays} shadow rays; seconds = render + "
          f"estimator preparation; median of {args.runs} seeds")
    for name, scene, ref, ref_noise in scene_list(args.scenes, args.res):
        print(f"\n{name}: {scene.n_triangles:,} triangles, {scene.camera.width}x{scene.camera.height}", flush=True)
        if ref is None:
            ref = reference(name, scene, args.ref_spp, args.ref_dir)
        for _, vis, opts in methods:  # compile, build and cache proxies outside the timed runs
            probvis.render(scene, spp=1, shadow_rays=1, visibility=vis, visibility_options=opts, resolution=(8, 8))
        rows = {m[0]: [] for m in methods}
        images = {m[0]: [] for m in methods}
        for seed in range(args.runs):
            for label, vis, opts in methods:
                r = probvis.render(scene, spp=args.spp, shadow_rays=args.shadow_rays, seed=seed, visibility=vis,
                                   visibility_options=opts)
                e = r.stats.get("estimator") or {}
                rows[label].append((relmse(r.image, ref), seconds(r.stats), e))
                images[label].append(r.image)
        if ref_noise == 0.0:  # a rendered reference: its noise is the exact renders' scaled by their spp ratio
            ref_noise = statistics.median(x[0] for x in rows["exact"]) * args.spp / args.ref_spp
        base = None
        for label, _, _ in methods:
            err = statistics.median(x[0] for x in rows[label])
            sec = statistics.median(x[1] for x in rows[label])
            eff = 1.0 / (err * sec)
            base = base or eff
            bias = (block_bias_ratio(images[label][0], images[label][1], ref, reference_noise=ref_noise)
                    if args.runs > 1 else None)
            extra = ""
            e = rows[label][-1][2]
            if "emitters" in e:
                em = e["emitters"][0]
                kinds = "/".join(sorted({p["kind"] for p in e["proxies"]})) or "none"
                extra = (f"  {kinds}, q {em['q'] if em['q'] is None else round(em['q'], 3)}, exact-only "
                         f"{em['exact_only']}, predicted gain {em['predicted_gain'] and round(em['predicted_gain'], 2)}, "
                         f"rho {e['cost_ratio'] and round(e['cost_ratio'], 3)}, delta "
                         f"{em['mismatch_energy'] and round(em['mismatch_energy'], 4)}, proxy triangles "
                         f"{e['proxy_triangles']:,}, tests proxy/scene nodes {e['tests']['proxy']['node']:,}/"
                         f"{e['tests']['scene']['node']:,}, proxies {e['seconds']['proxies']:.2f} s")
            if "shells" in e:
                sh = e["shells"]
                extra += (f"  shells solid/surface voxels {sh['solid_voxels']:,}/{sh['surface_voxels']:,}, "
                          f"voxels walked {e['tests']['shells']['voxel']:,}, scene nodes "
                          f"{e['tests']['scene']['node']:,}, {e['seconds']['shells']:.2f} s")
            print(f"  {label:15s} relMSE {err:.5f}  seconds {sec:6.2f}  efficiency {eff:9.1f}  vs exact "
                  f"{eff / base:5.2f}  bias {bias and round(bias, 2)}{extra}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
