"""Adaptive occlusion photon generation: more photons aimed where the map is uncertain.

Each round probes the map at a sample of its own photons; probes whose neighbourhood mixes light and shadow
photons are uncertain. New photon rays go from random points on the probe's emitter (its front side) to
points jittered around uncertain probes, and are traced like the first pass. Rounds stop when the candidate
lists of the uncertain probes stop growing (less than `GROWTH_STOP` relative growth), when no probe is
uncertain, or when the budget is spent.
"""
import numpy as np

from ...cases import CASE_PENUMBRA
from ...scene.scene import EMITTER_AREA, EMITTER_DIRECTIONAL, EMITTER_ENVIRONMENT, EMITTER_POINT
from .map import OcclusionMap
from .photons import ADAPTIVE_STREAM, Photons, points_on_emitters, trace_photons

PROBES = 16384  # photons probed per round
ROUNDS = 4
GROWTH_STOP = 0.05


def _classify_probes(omap, pos, nrm, emitter):
    """Case and candidate-list length of each probe with respect to its own emitter."""
    lk = omap.lookup(pos, nrm, share=False)
    own = np.arange(len(pos))
    lo, hi = lk.range(own, emitter)
    return lk.case[own, emitter], hi - lo


def refine(scene, bvh, emitters, photons: Photons, neighbours, groups, radius, budget, seed):
    """Add up to `budget` photon rays in rounds; returns the grown photon set, the lookup radius (fixed from
    the first pass so that rounds are comparable) and a per-round report."""
    rng = np.random.default_rng([seed, 0xADA])
    report = []
    spent = 0
    for r in range(ROUNDS):
        if spent >= budget or len(photons) == 0:
            break
        omap = OcclusionMap(photons, scene.n_emitters, neighbours, groups, radius)
        radius = omap.radius
        probe = rng.choice(len(photons), min(PROBES, len(photons)), replace=False)
        pos, nrm, pe = photons.position[probe], photons.normal[probe], photons.emitter[probe]
        case, length = _classify_probes(omap, pos, nrm, pe)
        uncertain = np.flatnonzero(case == CASE_PENUMBRA)
        entry = {"round": r + 1, "probes": len(probe), "uncertain_share": len(uncertain) / len(probe),
                 "mean_list_before": float(length[uncertain].mean()) if len(uncertain) else 0.0}
        if len(uncertain) == 0:
            entry["photons_added"] = 0
            report.append(entry)
            break
        n_new = int(min(budget - spent, max(len(photons) // 4, 1)))
        pick = uncertain[rng.integers(0, len(uncertain), n_new)]
        e = pe[pick]
        # targets: uniform in the disc of the lookup radius, in the tangent plane of the probe's surface
        n_t = nrm[pick]
        a = np.where(np.abs(n_t[:, :1]) > 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
        t1 = np.cross(n_t, a)
        t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
        t2 = np.cross(n_t, t1)
        rad = omap.radius * np.sqrt(rng.random(n_new))
        phi = 2 * np.pi * rng.random(n_new)
        target = pos[pick] + rad[:, None] * (np.cos(phi)[:, None] * t1 + np.sin(phi)[:, None] * t2)
        origin, n_e, _ = points_on_emitters(e.astype(np.int32), emitters.arrays, scene.triangles, seed,
                                            ADAPTIVE_STREAM, spent)
        kind = emitters.arrays.kind[e]
        # directional and environment light arrive along their "normal": start beyond the scene, aimed
        sun = (kind == EMITTER_DIRECTIONAL) | (kind == EMITTER_ENVIRONMENT)
        origin[sun] = target[sun] - 2.0 * emitters.arrays.sphere[3] * n_e[sun]
        d = target - origin
        cos_d = np.einsum("ij,ij->i", d, n_e) / np.maximum(np.linalg.norm(d, axis=1), 1e-300)
        # towards the emitter's front: an area emitter's side, anywhere for a point light, inside a spot's cone
        front = np.where(kind == EMITTER_AREA, cos_d > 0.0,
                         (kind == EMITTER_POINT) | sun | (cos_d > emitters.arrays.cone[e, 0]))
        new = trace_photons(scene, bvh, origin[front], d[front], e[front].astype(np.int32))
        photons = Photons.concatenate([photons, new])
        spent += n_new
        grown = OcclusionMap(photons, scene.n_emitters, neighbours, groups, radius)
        _, after = _classify_probes(grown, pos[uncertain], nrm[uncertain], pe[uncertain])
        entry.update(photons_added=int(front.sum()), mean_list_after=float(after.mean()))
        report.append(entry)
        if entry["mean_list_after"] <= (1.0 + GROWTH_STOP) * entry["mean_list_before"]:
            break
    return photons, radius, report
