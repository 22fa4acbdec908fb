"""How well `proxy --q auto`'s pilot predicts the gain it decides on, run by hand:
`python3 bench/bench_pilot_accuracy.py [--scenes heavy-canopy heavy-open-scan] [--res 256] [--spp 4]
[--shadow-rays 16] [--seeds 5] [--ref-spp 32]`.

Per scene and seed, exact visibility and `proxy` (auto q, no shells) render one after the other in this process,
with `proxy_plan.GAIN_MARGIN` set to 1 so that the pilot's plan is rendered whatever it predicts, and the cached
decision removed first (each seed's pilot runs, as a first render's would). Printed per seed: the predicted gain,
the mean q, both renders' relMSE against an exact reference (`--ref-spp` samples per pixel, made once and kept in
~/.cache/probvis/bench-references) and their seconds (render plus the estimator's preparation, pilot included), and
below them the pilot's measured costs (the proxy test, the extra exact test and the camera rays, relative to an
exact segment's), the render's seconds relative to exact visibility's as they predict (with the regions' mean q) and
as measured, and the proxy's preparation by phase. Then the measured gain over the seeds, 1 / (relMSE x seconds)
against exact visibility's, with the reference's own noise (exact's relMSE x spp / ref-spp) taken off both relMSEs,
and the range of the predictions: where the two ranges sit against GAIN_MARGIN is what the margin decides.
"""
import argparse
import shutil
import statistics
import warnings
from pathlib import Path

import numpy as np

import probvis
import probvis.visibility.proxy_plan as proxy_plan
from probvis.io import read_exr, write_exr

CACHE = Path.home() / ".cache" / "probvis"


def relmse(x, ref):
    return float(np.mean((x - ref) ** 2 / (ref ** 2 + 0.01)))


def seconds(stats):
    return stats["seconds"]["render"] + stats["seconds"]["prepare"]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["heavy-canopy", "heavy-open-scan"])
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--shadow-rays", type=int, default=16)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--ref-spp", type=int, default=32)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    margin, proxy_plan.GAIN_MARGIN = proxy_plan.GAIN_MARGIN, 1.0
    options = {"shells": False}
    print(f"{args.res}x{args.res}, {args.spp} spp x {args.shadow_rays} shadow rays, {args.seeds} seeds; GAIN_MARGIN "
          f"forced to 1 (its value: {margin})")
    for name in args.scenes:
        scene = probvis.load_scene(name, res=args.res)
        path = CACHE / "bench-references" / f"{name}-{args.res}-exact-{args.ref_spp}spp.exr"
        if not path.is_file():
            path.parent.mkdir(parents=True, exist_ok=True)
            write_exr(path, probvis.render(scene, spp=args.ref_spp, shadow_rays=16, seed=999).image)
        ref = read_exr(path).astype(np.float64)
        for vis, opts in (("exact", {}), ("proxy", options)):  # load the kernels, build the proxies
            probvis.render(scene, spp=1, shadow_rays=1, visibility=vis, visibility_options=opts, resolution=(8, 8))
        rows = []
        for seed in range(args.seeds):
            shutil.rmtree(CACHE / "plans", ignore_errors=True)
            exact = probvis.render(scene, spp=args.spp, shadow_rays=args.shadow_rays, seed=seed)
            proxy = probvis.render(scene, spp=args.spp, shadow_rays=args.shadow_rays, seed=seed, visibility="proxy",
                                   visibility_options=options)
            em = proxy.stats["estimator"]["emitters"][0]
            rows.append((relmse(exact.image, ref), seconds(exact.stats), relmse(proxy.image, ref),
                         seconds(proxy.stats), em["predicted_gain"], em["q"]))
            print(f"  {name} seed {seed}: predicted gain {em['predicted_gain'] or float('nan'):.3f}, q "
                  f"{em['q'] or float('nan'):.3f}; exact relMSE {rows[-1][0]:.5f} in {rows[-1][1]:.2f} s, proxy "
                  f"relMSE {rows[-1][2]:.5f} in {rows[-1][3]:.2f} s", flush=True)
            est, sec = proxy.stats["estimator"], proxy.stats["seconds"]
            rho, cost_e, kappa = est["cost_ratio"], est["exact_cost_ratio"], est["camera_cost_ratio"]
            predicted = ("1.00x (no proxy)" if em["q"] is None
                         else f"{(rho + em['q'] * cost_e + kappa) / (1 + kappa):.2f}x")
            print(f"    pilot: proxy cost {rho:.2f}, exact test {cost_e:.2f}, camera {kappa:.2f} of exact's segments: "
                  f"render predicted {predicted} of exact's, measured "
                  f"{sec['render'] / exact.stats['seconds']['render']:.2f}x; proxy prepare {sec['prepare']:.2f} s "
                  f"({', '.join(f'{k} {v:.2f}' for k, v in est['seconds'].items() if v >= 0.005)})", flush=True)
        e_err, e_sec, p_err, p_sec = (statistics.mean(r[i] for r in rows) if i in (0, 2) else
                                      statistics.median(r[i] for r in rows) for i in range(4))
        noise = e_err * args.spp / args.ref_spp
        predicted = [r[4] for r in rows if r[4] is not None]
        gain = (e_err - noise) * e_sec / ((p_err - noise) * p_sec)
        print(f"{name}: measured gain {gain:.2f} (relMSE mean, seconds median over the seeds); predicted "
              f"{min(predicted):.2f}-{max(predicted):.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
