"""What limits proxy visibility's gain on the canopy at few shadow rays, run by hand:
`python3 bench/bench_canopy_limit.py [--pixels 3000]`.

On heavy-canopy (256x256), the shadow segments of a random set of pixels (one camera sample each, 16 segments
per hit, as a 4x16 render draws them) are tested exactly (V) and against the volumetric proxy (T, the
transmittance of the leaves' extinction grid). Printed: how well T predicts V (correlation, the mismatch energy
sum((V - T) w)^2 with w the luminance of the segment's unoccluded contribution) at grid resolutions 32-256;
the correction's variance x cost of q per segment in proportion to w (what `proxy_kernel.segment_q` does), to
w sqrt(T (1 - T)) (the expected |V - T| of a calibrated proxy) and to the oracle |V - T| w, each relative to
one q for all segments; and the share of the mismatch left within a shading point's segments (the most that
drawing a fixed number of corrections per point, instead of independent coins, could remove is the rest).
"""
import argparse

import numpy as np

import probvis
from probvis import transmittance as tr
from probvis.accel import build_bvh, occluded_segments
from probvis.emitters import build_emitter_sampler
from probvis.integrator import Integrator


def allocation_gain(m, s):
    """Variance x cost of the correction with q per segment in proportion to s, against one q for all:
    (sum m)(n) / ((sum m / s)(sum s))."""
    s = np.maximum(s, 1e-3 * s.max())
    return m.sum() * len(m) / ((m / s).sum() * s.sum())


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pixels", type=int, default=3000)
    args = ap.parse_args()
    scene = probvis.load_scene("heavy-canopy", res=256)
    bvh = build_bvh(scene.triangles)
    integrator = Integrator(scene, bvh, build_emitter_sampler(scene))
    pixels = np.sort(np.random.default_rng(0).choice(256 * 256, args.pixels, replace=False))
    q = integrator.shadow_query(integrator.shading_batch(pixels, 1, 16, 7))
    v = 1.0 - occluded_segments(bvh, q.origin, q.direction, q.tmax, q.point)[0]
    w = q.weight
    leaves = max((s for s in scene.shapes if s.emitter < 0), key=lambda s: s.n_triangles)
    tris = scene.triangles[leaves.first_triangle:leaves.first_triangle + leaves.n_triangles]
    print(f"heavy-canopy, {len(v):,} segments of {args.pixels} pixels; mean V {v.mean():.3f}")
    for res in (32, 64, 128, 256):
        t, steps = tr.transmittances(tr.extinction_grid([tris], res).arrays, q.origin, q.direction, q.tmax)
        m = ((v - t) * w) ** 2
        print(f"grid {res:>3}: corr(V, T) {np.corrcoef(v, t)[0, 1]:.3f}, mismatch energy {m.sum():.4g}, "
              f"mean T - mean V {t.mean() - v.mean():+.4f}, voxels per segment {np.mean(steps):.1f}")
        if res == 64:  # the proxy's own resolution (transmittance.RESOLUTION)
            kept = (t, m)
    t, m = kept
    for label, s in (("w", w), ("w sqrt(T (1 - T))", w * np.sqrt(t * (1 - t))), ("oracle |V - T| w", np.sqrt(m))):
        print(f"q per segment in proportion to {label}: the correction's variance x cost "
              f"{allocation_gain(m, s):.2f}x lower than with one q")
    _, point = np.unique(q.point, return_inverse=True)
    d = (v - t) * w
    within = d - (np.bincount(point, d) / np.bincount(point))[point]
    print(f"mismatch left within a shading point's segments: {np.sum(within ** 2) / np.sum(d ** 2):.3f}")


if __name__ == "__main__":
    main()
