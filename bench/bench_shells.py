"""The shells' grid walk against the exact test, side by side, run by hand:
`python3 bench/bench_shells.py [--segments 2000000] [--runs 3] [--resolutions 32 64 128]`.

On heavy-scan, segments from random points of the scene's surfaces (by area, lifted off them) to random points
of its light: the exact any-hit test (`accel.occluded_segments`, packets of 32 in random order) and the walk of
the shells' grid (`shells.classify_segments`) at each resolution, fastest of `--runs`; the shares the walk
decides (SOLID: blocked, FREE: clear of the heavy mesh), checked against the exact answers; and the time to
build the proxies and the shells without the cache and from it.
"""
import argparse
import os
import tempfile
import time

import numpy as np

import probvis
from probvis.accel import build_bvh, occluded_segments
from probvis.proxies import build_proxies
from probvis.shells import FREE, SOLID, build_shells, classify_segments, heavy_meshes


def surface_points(tris, weights, n, rng):
    """n uniform points on triangles drawn with probability proportional to `weights`, and their unit normals."""
    t = rng.choice(len(tris), n, p=weights / weights.sum())
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
    nrm = np.cross(b - a, c - a)
    return a + u[:, None] * (b - a) + v[:, None] * (c - a), nrm / np.linalg.norm(nrm, axis=1, keepdims=True)


def fastest(runs, fn):
    best, out = np.inf, None
    for _ in range(runs):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--segments", type=int, default=2_000_000)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--resolutions", type=int, nargs="+", default=[32, 64, 128])
    args = ap.parse_args()

    scene = probvis.load_scene("heavy-scan")
    tris = scene.triangles
    bvh = build_bvh(tris)
    light = next(s for s in scene.shapes if s.emitter >= 0)
    lit = slice(light.first_triangle, light.first_triangle + light.n_triangles)
    area = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
    area[lit] = 0.0
    rng = np.random.default_rng(1)
    org, nrm = surface_points(tris, area, args.segments, rng)
    end, _ = surface_points(tris[lit], np.ones(light.n_triangles), args.segments, rng)
    nrm *= np.sign(np.einsum("ij,ij->i", nrm, end - org))[:, None]
    org += 1e-4 * nrm
    d = end - org
    tmax = np.full(len(org), 1 - 1e-4)
    point = np.arange(len(org)) // 32
    print(f"heavy-scan: {len(tris):,} triangles; {len(org):,} segments, fastest of {args.runs}")

    t_exact, (occ, n_node, _) = fastest(args.runs, lambda: occluded_segments(bvh, org, d, tmax, point))
    print(f"  exact test      {t_exact:6.3f} s   {n_node.mean():5.1f} nodes/segment, occluded {occ.mean():.3f}")
    with tempfile.TemporaryDirectory() as cache:
        for res in args.resolutions:
            sh = build_shells(scene, bvh, heavy_meshes(scene, 100_000), resolution=res, use_cache=False)
            t_walk, (state, steps, _) = fastest(args.runs, lambda: classify_segments(sh.grid, sh.lo, sh.pitch, org, d,
                                                                                     tmax))
            wrong = int(((state == SOLID) & ~occ).sum() + ((state == FREE) & occ).sum())
            print(f"  walk at {res:3d}     {t_walk:6.3f} s   {t_walk / t_exact:.3f} of the exact test, "
                  f"{steps.mean():5.1f} voxels/segment; blocked {np.mean(state == SOLID):.3f}, "
                  f"clear {np.mean(state == FREE):.3f}, undecided {np.mean((state != SOLID) & (state != FREE)):.3f}; "
                  f"disagreeing with exact {wrong}; built in {sh.seconds:.2f} s")
        os.environ["PROBVIS_CACHE_DIR"] = cache
        for label in ("without the cache", "from the cache"):
            t0 = time.perf_counter()
            build_proxies(scene)
            t_proxy = time.perf_counter() - t0
            sh = build_shells(scene, bvh, heavy_meshes(scene, 100_000))
            print(f"  {label:17s}: proxies {t_proxy:.2f} s, shells {sh.seconds:.2f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
