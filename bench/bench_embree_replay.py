"""Exact visibility against the hardware's limit, run by hand:
`python3 bench/bench_embree_replay.py [--scenes cornell-bunny city leaves heavy-scan] [--res 128] [--shadow-rays 16]`.

The renderer's own shadow segments (camera rays to their first hits, then `--shadow-rays` segments per hit to
the emitters, from `Integrator.shading_batch` and `shadow_query`, one sample per pixel, both ends pulled in
by 1e-5 of the scene's diagonal) are replayed through
probvis's packet traversal (`accel.occluded_segments`: from the shading point, as the renderer traces them, with
the pull as the segment's start `tmin`) and through Embree 4 (`pip install embreex`: one `rtcOccluded` per ray,
float32, from the pulled origin), one thread each, best of `--rounds`. Prints millions of segments per second,
their ratio, the occluded shares (and where the two disagree: Embree's float32 test is not watertight) and
probvis's node and triangle tests per segment. A name is a built-in scene or, with ../shared beside the
project, one of its scenes. Numba's threads are set to one before probvis is imported.
"""
import argparse
import os
import time
from pathlib import Path

os.environ["NUMBA_NUM_THREADS"] = "1"

import numpy as np  # noqa: E402

import probvis  # noqa: E402
from probvis.accel import build_bvh, occluded_segments  # noqa: E402
from probvis.emitters import build_emitter_sampler  # noqa: E402
from probvis.integrator import Integrator  # noqa: E402

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


def segments(scene, bvh, shadow_rays, seed=1):
    """The render's shadow segments of one camera sample per pixel: origin, direction, tmin, tmax, shading point.
    Both ends are pulled in by 1e-5 of the scene's diagonal (`tmin` is the pull): the renderer's offset off the
    surface is made for double precision, and in float32 Embree would find the surface a segment leaves."""
    integrator = Integrator(scene, bvh, build_emitter_sampler(scene))
    pixels = np.arange(scene.camera.width * scene.camera.height)
    query = integrator.shadow_query(integrator.shading_batch(pixels, 1, shadow_rays, seed))
    lo, hi = bvh.bounds[0, :3], bvh.bounds[0, 3:]
    length = np.linalg.norm(query.direction, axis=1)
    pull = 1e-5 * np.linalg.norm(hi - lo) / length  # in units of t
    return query.origin, query.direction, pull, query.tmax - pull, query.point


def best_of(rounds, run):
    out, best = None, np.inf
    for _ in range(rounds):
        t0 = time.perf_counter()
        out = run()
        best = min(best, time.perf_counter() - t0)
    return out, best


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", nargs="+", default=["cornell-bunny", "city", "leaves"])
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--shadow-rays", type=int, default=16)
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    print(f"{args.res}x{args.res}, 1 camera sample per pixel x {args.shadow_rays} shadow segments, one thread, "
          f"best of {args.rounds}")
    for name in args.scenes:
        path = SHARED / "scenes" / f"{name}.xml"
        if name in probvis.BUILTINS:
            scene = probvis.load_scene(name, res=args.res)
        elif path.is_file():
            scene = probvis.load_scene(path, res=args.res)
        else:
            print(f"{name}: not a built-in and ../shared not found, skipped")
            continue
        tris = np.ascontiguousarray(scene.triangles, dtype=np.float64)
        bvh = build_bvh(tris)
        org, d, tmin, tmax, point = segments(scene, bvh, args.shadow_rays)
        n = len(tmax)
        occluded_segments(bvh, org[:64], d[:64], tmax[:64], point[:64], tmin[:64])  # load the kernel
        (occ, nodes, tests), ours = best_of(args.rounds, lambda: occluded_segments(bvh, org, d, tmax, point, tmin))
        embree = rtcore_scene.EmbreeScene()
        TriangleMesh(embree, tris.astype(np.float32))
        o32 = (org + tmin[:, None] * d).astype(np.float32)
        d32, t32 = d.astype(np.float32), (tmax - tmin).astype(np.float32)
        hits, theirs = best_of(args.rounds, lambda: embree.run(o32, d32, query="OCCLUDED", dists=t32))
        occ_e = np.asarray(hits) != -1
        print(f"{name}: {len(tris):,} triangles, {n:,} segments, occluded {np.mean(occ):.3f} (Embree "
              f"{np.mean(occ_e):.3f}, disagree on {np.mean(occ.astype(bool) != occ_e):.2%}); probvis "
              f"{n / ours / 1e6:.2f} M/s ({np.mean(nodes):.1f} node and {np.mean(tests):.1f} triangle tests a "
              f"segment), Embree {n / theirs / 1e6:.2f} M/s: ratio {theirs / ours:.2f}")


if __name__ == "__main__":
    main()
