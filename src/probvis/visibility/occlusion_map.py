"""Occlusion-map visibility: photons classify shading points; only penumbra points get shadow rays, and
those are tested against the point's candidate blockers (`penumbra="list"`) or the whole BVH ("bvh")."""
import math
import time
import warnings

import numpy as np
from numba import njit, prange

from ..accel import occluded_segments
from ..accel.traversal import hit_triangle, ray_setup
from ..errors import ProbvisError
from ..geometry import unit_normals
from ..occlusion_map import (OcclusionMap, closed_orientation, components, refine, shoot_photons,
                             blocker_groups)
from .base import CASE_PENUMBRA, CASE_UNKNOWN, VisibilityEstimator, VisibilityResult

DEFAULT_NEIGHBOURS = 32
PHOTONS_PER_CAMERA_SAMPLE = 0.5  # default photon budget: half a photon ray per camera sample ...
MIN_PHOTONS_DEFAULT = 100_000  # ... but at least this many
ADAPTIVE_SHARE = 0.5  # adaptive rounds may add up to this share of the first pass's photons
GROUP_COMPONENTS = 64  # a recorded blocker brings its whole connected component if that is this small


@njit(cache=True, error_model="numpy", inline="always")
def culled(orientation, fnormal, t, dx, dy, dz):
    """Volumetric culling: a closed component's triangle that faces away from the segment's far end."""
    o = orientation[t]
    return o != 0 and o * (fnormal[t, 0] * dx + fnormal[t, 1] * dy + fnormal[t, 2] * dz) <= 0.0


@njit(cache=True, error_model="numpy", inline="always")
def first_blocker(triangles, orientation, fnormal, ox, oy, oz, dx, dy, dz, tmax, tris, lo, hi):
    """Test candidates tris[lo:hi] in order until one blocks the segment.

    Returns (blocked, triangle tests, culled candidates)."""
    kx, ky, kz, sx, sy, sz = ray_setup(dx, dy, dz)
    o = (ox, oy, oz)
    n_tri, n_cull = 0, 0
    for c in range(lo, hi):
        t = tris[c]
        if culled(orientation, fnormal, t, dx, dy, dz):
            n_cull += 1
            continue
        n_tri += 1
        if hit_triangle(triangles, t, o, kx, ky, kz, sx, sy, sz, 0.0, tmax)[0] < np.inf:
            return True, n_tri, n_cull
    return False, n_tri, n_cull


@njit(cache=True, parallel=True, error_model="numpy")
def visibility_from_lists(triangles, orientation, fnormal, org, dirs, tmax, lo, hi, tris):
    """Visibility of each segment against its own candidate list tris[lo[s]:hi[s]]."""
    n = org.shape[0]
    vis = np.ones(n)
    n_tri = np.zeros(n, np.int32)
    n_cull = np.zeros(n, np.int32)
    for s in prange(n):
        blocked, a, b = first_blocker(triangles, orientation, fnormal, org[s, 0], org[s, 1], org[s, 2], dirs[s, 0],
                                      dirs[s, 1], dirs[s, 2], tmax[s], tris, lo[s], hi[s])
        if blocked:
            vis[s] = 0.0
        n_tri[s], n_cull[s] = a, b
    return vis, n_tri, n_cull


def _positive_int(name, value):
    if isinstance(value, bool) or int(value) != value or value < 1:
        raise ProbvisError(f"{name} must be a positive integer, got {value}")
    return int(value)


class OcclusionMapVisibility(VisibilityEstimator):
    """Photons -> cases per shading point and emitter -> shadow rays only in the penumbra.

    `photons`: photon rays of the first pass (None: half a ray per camera sample, at least 100k);
    `neighbours`: photons looked up per point; `radius`: look-up radius (None: twice the median distance from a
    photon to its k-th neighbour); `penumbra`: "bvh" (whole scene, unbiased in the penumbra) or "list" (the
    candidate blockers only: fewer tests, biased where photons missed a blocker); `adaptive`: extra photons
    aimed at uncertain regions; `volumetric`: in list mode, skip closed meshes' triangles facing away from the
    light end of a segment.
    """

    name = "occlusion-map"

    def __init__(self, photons=None, neighbours=DEFAULT_NEIGHBOURS, radius=None, penumbra="bvh", adaptive=False,
                 volumetric=True):
        self.n_photons = None if photons is None else _positive_int("photons", photons)
        self.k = _positive_int("neighbours", neighbours)
        if radius is not None and not (math.isfinite(radius) and radius > 0):
            raise ProbvisError(f"radius must be a positive number, got {radius}")
        if penumbra not in ("list", "bvh"):
            raise ProbvisError(f"penumbra must be 'list' or 'bvh', got '{penumbra}'")
        self.radius, self.penumbra = radius, penumbra
        self.adaptive, self.volumetric = bool(adaptive), bool(volumetric)
        self._stats = {}

    def options(self):
        return {"photons": self.n_photons, "neighbours": self.k, "radius": self.radius, "penumbra": self.penumbra,
                "adaptive": self.adaptive, "volumetric": self.volumetric}

    def prepare(self, scene, bvh, emitters):
        super().prepare(scene, bvh, emitters)
        cam = scene.camera
        n = self.n_photons or max(MIN_PHOTONS_DEFAULT,
                                  int(PHOTONS_PER_CAMERA_SAMPLE * cam.width * cam.height * scene.spp))
        t_geom = time.perf_counter()
        self.fnormal = unit_normals(scene.triangles)
        n_tri = scene.n_triangles
        self.orientation = np.zeros(n_tri, np.int8)
        if self.penumbra == "list":
            comps = components(scene)
            if self.volumetric:  # only where the list holds the whole component, so its exit face too
                whole = np.bincount(comps[0])[comps[0]] <= GROUP_COMPONENTS
                self.orientation = np.where(whole, closed_orientation(scene, comps), 0).astype(np.int8)
            groups = blocker_groups(comps[0], comps[2], GROUP_COMPONENTS)
        else:  # lists are not used: each triangle stands for itself
            groups = (np.arange(n_tri, dtype=np.int32), np.arange(n_tri + 1, dtype=np.int64),
                      np.arange(n_tri, dtype=np.int32))
        t_geom = time.perf_counter() - t_geom
        t0 = time.perf_counter()
        photons = shoot_photons(scene, bvh, emitters, n, scene.seed)
        t1 = time.perf_counter()
        first = len(photons)
        rounds, radius = [], self.radius
        if self.adaptive and len(photons):
            photons, radius, rounds = refine(scene, bvh, emitters, photons, self.k, groups, radius,
                                             int(ADAPTIVE_SHARE * n), scene.seed)
        t2 = time.perf_counter()
        self.map = OcclusionMap(photons, scene.n_emitters, self.k, groups, radius)
        t3 = time.perf_counter()
        if len(photons) == 0:
            warnings.warn(f"occlusion map: no photon of scene '{scene.name}' hit anything; every point is "
                          "'unknown' and tested against the whole scene (exact visibility)", stacklevel=2)
        shadow = photons.shadow
        self._stats = {
            "photon_rays": photons.rays, "photon_rays_first_pass": n, "photons": len(photons),
            "photons_first_pass": first, "light_photons": int((~shadow).sum()), "shadow_photons": int(shadow.sum()),
            "radius": self.map.radius, "neighbours": self.k,
            "photon_tests": {"triangle": photons.triangle_tests, "node": photons.node_tests},
            "closed_triangles": int((self.orientation != 0).sum()),
            "adaptive_rounds": rounds,
            "seconds": {"photons": t1 - t0, "adaptive": t2 - t1, "map_build": t3 - t2 + t_geom, "lookup": 0.0},
            "list_length": {"mean": None, "max": None, "penumbra_pairs": 0},
            "culled_candidates": 0, "penumbra_shadow_rays": 0, "unknown_shadow_rays": 0,
        }
        self._list_sum = 0

    def classify(self, points):
        t0 = time.perf_counter()
        tri = points.triangle
        shaded = tri >= 0
        g = self.fnormal[np.maximum(tri, 0)]
        g = np.where((np.einsum("ij,ij->i", g, points.normal) < 0)[:, None], -g, g)
        g[~shaded] = 0.0
        self.normals = g  # geometric normals on the shading normal's side, zero where not shaded
        with_lists = self.penumbra == "list"
        self.lookup = self.map.lookup(points.position, g, with_lists=with_lists)
        lk, st = self.lookup, self._stats
        pen = lk.case == CASE_PENUMBRA
        ll = st["list_length"]
        ll["penumbra_pairs"] += int(pen.sum())
        if with_lists:
            m = lk.case.shape[0]
            lo, hi = lk.range(np.arange(m)[:, None], np.arange(self.scene.n_emitters)[None, :])
            lengths = (hi - lo)[pen]
            self._list_sum += int(lengths.sum())
            ll["max"] = max(ll["max"] or 0, int(lengths.max()) if len(lengths) else 0)
            ll["mean"] = self._list_sum / max(1, ll["penumbra_pairs"])
        st["seconds"]["lookup"] += time.perf_counter() - t0
        return lk.case

    def segment_lists(self, query, idx):
        """Candidate-list range [lo, hi) of each segment in idx."""
        return self.lookup.range(query.point[idx], query.emitter[idx])

    def evaluate(self, query):
        n = len(query.tmax)
        value = np.ones(n)
        n_node = np.zeros(n, np.int32)
        n_tri = np.zeros(n, np.int32)
        case = self.lookup.case[query.point, query.emitter]
        on_bvh = (case == CASE_UNKNOWN) | ((case == CASE_PENUMBRA) if self.penumbra == "bvh" else False)
        idx = np.flatnonzero(on_bvh)
        if len(idx):
            occ, a, b = occluded_segments(self.bvh, query.origin[idx], query.direction[idx], query.tmax[idx],
                                          query.point[idx])
            value[idx], n_node[idx], n_tri[idx] = 1.0 - occ, a, b
        self._stats["unknown_shadow_rays"] += int((case == CASE_UNKNOWN).sum())
        self._stats["penumbra_shadow_rays"] += int((case == CASE_PENUMBRA).sum())
        if self.penumbra == "list":
            idx = np.flatnonzero(case == CASE_PENUMBRA)
            if len(idx):
                value[idx], n_tri[idx] = self.evaluate_penumbra(query, idx)
        return VisibilityResult(value, n_node, n_tri)

    def evaluate_penumbra(self, query, idx):
        """Visibility and triangle tests of the penumbra segments idx against their candidate lists."""
        lo, hi = self.segment_lists(query, idx)
        vis, n_tri, n_cull = visibility_from_lists(self.scene.triangles, self.orientation, self.fnormal, query.origin[idx],
                                        query.direction[idx], query.tmax[idx], lo, hi, self.lookup.tris)
        self._stats["culled_candidates"] += int(n_cull.sum())
        return vis, n_tri

    def stats(self):
        return self._stats
