"""Conservative shells around and inside heavy meshes: visibility decided exactly, with no variance, for the
segments they apply to (the bounding and inner envelopes of Cohen et al.'s simplification envelopes, built on
a voxel grid rather than by offsetting, because a grid is conservative by construction).

On a grid of `resolution` voxels along the longest side of the heavy meshes' bounds, every voxel that a heavy
triangle's bounding box touches (padded) is marked SURFACE. The unmarked voxels split into 6-connected regions;
each contains no surface, so it lies wholly inside or wholly outside every mesh. A region not touching the
grid's border is inside a watertight mesh when rays from its voxels cross that mesh an odd number of times
(three rays from three voxels, all odd); its voxels are SOLID. Then, walking the voxels a segment passes
through (`segment_class`, a 3D-DDA after Amanatides and Woo):

- the **inner shell** is the boundary of the SOLID voxels, strictly inside closed meshes: a segment entering a
  SOLID voxel passes through a mesh's solid interior, so it crosses the mesh and is blocked (its ends are
  outside the mesh: a closed mesh with an emitter in its bounds gets no SOLID voxels);
- the **outer shell** is the boundary of the SURFACE and SOLID voxels and contains every heavy mesh: a segment
  that visits no such voxel cannot meet a heavy mesh, so only the rest of the scene can block it.

The walk visits at most a few hundred bytes of a grid that stays in cache, where the BVH of a heavy mesh does
not. Grids are cached on disk (`disk_cache`) keyed by the heavy meshes, the emitters and the resolution.
"""
import time
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from .disk_cache import content_key, load_or_build
from .scene.scene import EMITTER_POINT, EMITTER_SPOT
from .voxels import bounds, grid_placement, walk_start, walk_step

RESOLUTION = 64  # voxels along the longest side of the heavy meshes' bounds
PAD = 1e-3  # triangle bounds are padded by this fraction of a voxel: a segment leaving a heavy mesh starts inside
PARITY_CAP = 4096  # hits counted per parity ray; a ray that reaches it decides nothing
PARITY_DIRECTIONS = np.array([[0.5773, 0.5774, 0.5773], [-0.6402, 0.3197, 0.6985], [0.2113, -0.8660, 0.4531]])
CACHE_VERSION = 2
FREE, SURFACE, SOLID = 0, 1, 2  # voxel states; also `segment_class`'s answers: clear, undecided, blocked


@dataclass
class Shells:
    """The voxel grid of the shells (FREE, SURFACE, SOLID per voxel) and which shapes they cover."""

    grid: np.ndarray  # (X, Y, Z) uint8
    lo: np.ndarray  # (3,) the grid's corner
    pitch: float  # its voxel size
    shapes: list  # dicts: name, triangles, closed (has SOLID voxels)
    seconds: float = 0.0
    cached: bool = False

    @property
    def solid_voxels(self):
        return int((self.grid == SOLID).sum())

    @property
    def surface_voxels(self):
        return int((self.grid == SURFACE).sum())


@njit(cache=True)
def _mark(tris, lo, pitch, pad, dims, grid):
    """Mark every voxel that a triangle's bounding box, padded by `pad`, touches."""
    for t in range(tris.shape[0]):
        i0 = np.empty(3, np.int64)
        i1 = np.empty(3, np.int64)
        for a in range(3):
            mn = min(tris[t, 0, a], tris[t, 1, a], tris[t, 2, a]) - pad
            mx = max(tris[t, 0, a], tris[t, 1, a], tris[t, 2, a]) + pad
            i0[a] = max(0, min(dims[a] - 1, np.int64(np.floor((mn - lo[a]) / pitch))))
            i1[a] = max(0, min(dims[a] - 1, np.int64(np.floor((mx - lo[a]) / pitch))))
        for x in range(i0[0], i1[0] + 1):
            for y in range(i0[1], i1[1] + 1):
                for z in range(i0[2], i1[2] + 1):
                    grid[x, y, z] = True


@njit(cache=True, error_model="numpy", inline="always")
def segment_class(grid, lo, pitch, ox, oy, oz, dx, dy, dz, tmax):
    """Walk the voxels the segment o + t d, t in [0, tmax], passes through: SOLID (it crosses an inner shell:
    blocked), SURFACE (it meets the outer shells: undecided) or FREE (clear of every heavy mesh); the voxels
    visited; and for SURFACE the t range from entering its first SURFACE voxel to leaving its last, widened by
    half the padding (a heavy mesh can block it only there)."""
    nx, ny, nz = grid.shape
    t0, t1, i, j, k, si, sj, sk, tx, ty, tz, dtx, dty, dtz = walk_start(nx, ny, nz, lo, pitch, ox, oy, oz, dx, dy,
                                                                        dz, tmax)
    if t0 > t1:
        return FREE, 0, 0.0, 0.0
    state, steps = FREE, 0
    t_in, first, last = t0, tmax, 0.0
    inside = True
    while inside:
        g = grid[i, j, k]
        steps += 1
        if g == SOLID:
            return SOLID, steps, 0.0, 0.0
        t_out = min(tx, ty, tz)
        if g == SURFACE:
            state = SURFACE
            first = min(first, t_in)
            last = max(last, min(t_out, t1))
        if t_out > t1:
            break
        t_in = t_out
        i, j, k, tx, ty, tz, inside = walk_step(i, j, k, si, sj, sk, tx, ty, tz, dtx, dty, dtz, nx, ny, nz)
    if state == FREE:
        return FREE, steps, 0.0, 0.0
    margin = 0.5 * PAD * pitch / (abs(dx) + abs(dy) + abs(dz))
    return SURFACE, steps, max(0.0, first - margin), min(tmax, last + margin)


@njit(cache=True, parallel=True, error_model="numpy")
def classify_segments(grid, lo, pitch, org, dirs, tmax):
    """`segment_class` of each segment: its class, voxels visited and the t range of its SURFACE voxels."""
    n = len(org)
    out, steps, t_range = np.empty(n, np.uint8), np.empty(n, np.int32), np.empty((n, 2))
    for s in prange(n):
        out[s], steps[s], t_range[s, 0], t_range[s, 1] = segment_class(
            grid, lo, pitch, org[s, 0], org[s, 1], org[s, 2], dirs[s, 0], dirs[s, 1], dirs[s, 2], tmax[s])
    return out, steps, t_range


def is_closed(tris):
    """Whether a triangle soup, its equal corners welded, is watertight: every edge shared by exactly two
    triangles. Hash tables in one pass (`_closed`): a quarter of a second for 1.3M triangles, where welding by
    sorting took 1.6 s."""
    corners = np.ascontiguousarray(tris, dtype=np.float64).reshape(-1, 3)
    return bool(len(corners)) and _closed(corners.view(np.uint64))


@njit(cache=True)
def _slot(h, mask):
    """A hash table slot from a 64-bit hash (its high bits mixed in)."""
    return np.int64((h ^ (h >> np.uint64(29))) & mask)


@njit(cache=True)
def _closed(bits):
    """`is_closed` of the corners' coordinates as bit patterns ((3n, 3) uint64): corners welded by exact equality
    (open addressing), then each undirected edge (lower, higher vertex) counted; closed when every count is 2."""
    n = bits.shape[0]
    size = 1
    while size < 2 * n:
        size *= 2
    mask = np.uint64(size - 1)
    slot_vertex = np.full(size, -1, np.int64)
    vertex_corner = np.empty(n, np.int64)  # a corner of each welded vertex, for comparisons
    vid = np.empty(n, np.int64)
    m1, m2, m3 = np.uint64(0x9E3779B97F4A7C15), np.uint64(0xC2B2AE3D27D4EB4F), np.uint64(0x165667B19E3779F9)
    nv = 0
    for c in range(n):
        s = _slot(bits[c, 0] * m1 ^ bits[c, 1] * m2 ^ bits[c, 2] * m3, mask)
        while True:
            v = slot_vertex[s]
            if v < 0:
                slot_vertex[s], vertex_corner[nv], vid[c] = nv, c, nv
                nv += 1
                break
            o = vertex_corner[v]
            if bits[o, 0] == bits[c, 0] and bits[o, 1] == bits[c, 1] and bits[o, 2] == bits[c, 2]:
                vid[c] = v
                break
            s = (s + 1) & (size - 1)
    slot_edge = np.full(size, -1, np.int64)  # n edges in 2n slots
    count = np.zeros(size, np.int64)
    for t in range(n // 3):
        for k in range(3):
            a, b = vid[3 * t + k], vid[3 * t + (k + 1) % 3]
            key = min(a, b) * nv + max(a, b)
            s = _slot(np.uint64(key) * m1, mask)
            while slot_edge[s] >= 0 and slot_edge[s] != key:
                s = (s + 1) & (size - 1)
            slot_edge[s] = key
            count[s] += 1
            if count[s] > 2:
                return False
    for s in range(size):
        if slot_edge[s] >= 0 and count[s] != 2:
            return False
    return True


def _inside_regions(labels, n_labels, lo, pitch, bvh, first, count):
    """Labels of the empty regions (`labels` of the unmarked voxels) inside the mesh of scene triangles
    first..first+count: not touching the grid's border, and every parity ray from three of their voxels crosses
    it an odd number of times."""
    from scipy import ndimage  # scipy is imported where used: a render without shells never needs it

    from .accel import all_hits

    border = np.unique(np.concatenate([labels[[0, -1]].ravel(), labels[:, [0, -1]].ravel(),
                                       labels[:, :, [0, -1]].ravel()]))
    candidates = np.setdiff1d(np.arange(1, n_labels + 1), border)
    if len(candidates) == 0:
        return candidates
    where = ndimage.find_objects(labels)
    points, owner = [], []
    for lab in candidates:
        idx = np.argwhere(labels[where[lab - 1]] == lab) + [s.start for s in where[lab - 1]]
        for v in idx[[0, len(idx) // 2, -1]]:
            points.append(lo + (v + 0.5) * pitch)
            owner.append(lab)
    org = np.repeat(np.array(points), len(PARITY_DIRECTIONS), axis=0)
    dirs = np.tile(PARITY_DIRECTIONS, (len(points), 1))
    n, tri, _, _, _ = all_hits(bvh.arrays, org, dirs, np.zeros(len(org)), PARITY_CAP)
    mine = (tri >= first) & (tri < first + count)
    odd = (mine.sum(axis=1) % 2 == 1) & (n < PARITY_CAP)
    owner = np.repeat(np.array(owner), len(PARITY_DIRECTIONS))
    inside = np.ones(n_labels + 1, bool)
    np.logical_and.at(inside, owner, odd)
    return candidates[inside[candidates]]


def heavy_meshes(scene, min_triangles):
    """The scene's shapes of at least `min_triangles` triangles that are not emitters."""
    return [s for s in scene.shapes if s.n_triangles >= min_triangles and s.emitter < 0]


def mesh_closed(tris, use_cache=True):
    """Whether a mesh is closed (`is_closed`), cached on disk by the triangles' content: the hash takes 3 ms for
    a million triangles, the test a quarter of a second."""
    def build():
        return {"closed": np.array(is_closed(tris))}

    out, _ = load_or_build("closed", content_key(f"mesh closed v{CACHE_VERSION}", tris), build, use_cache,
                           {"closed": ((), "b")})
    return bool(out["closed"])


def span(scene, shape):
    """The triangles of one of the scene's shapes."""
    return scene.triangles[shape.first_triangle:shape.first_triangle + shape.n_triangles]


def emitter_boxes(scene):
    """Bounds of the emitting shapes and of the point and spot lights (as empty boxes), (n, 2, 3)."""
    boxes = np.array([(s.lo, s.hi) for s in scene.shapes if s.emitter >= 0]).reshape(-1, 2, 3)
    points = scene.emitter_position[np.isin(scene.emitter_kind, (EMITTER_POINT, EMITTER_SPOT))]
    return np.concatenate([boxes, np.stack([points, points], axis=1)])


def build_shells(scene, bvh, heavy, resolution=RESOLUTION, use_cache=True):
    """`Shells` of the scene's shapes `heavy` (`heavy_meshes`), or None when there are none."""
    t0 = time.perf_counter()
    if not heavy:
        return None
    spans = [span(scene, s) for s in heavy]
    boxes = emitter_boxes(scene)
    key = content_key(f"shells v{CACHE_VERSION} resolution {resolution}", boxes, *spans)

    def build():
        mesh_boxes = np.array([bounds(t) for t in spans])
        lo, hi = mesh_boxes[:, 0].min(axis=0), mesh_boxes[:, 1].max(axis=0)
        lo, pitch, dims = grid_placement(lo, hi, resolution)  # the border region is outside
        grid = np.zeros(dims, np.uint8)
        closed = []
        for shape, tris, (mesh_lo, mesh_hi) in zip(heavy, spans, mesh_boxes):
            marked = np.zeros(dims, bool)
            _mark(tris, lo, pitch, PAD * pitch, dims, marked)
            ok = not overlaps(boxes, mesh_lo, mesh_hi) and is_closed(tris)
            inside = np.zeros(dims, bool)
            if ok:
                from scipy import ndimage

                labels, n_labels = ndimage.label(~marked)
                inside = np.isin(labels, _inside_regions(labels, n_labels, lo, pitch, bvh,
                                                         shape.first_triangle, shape.n_triangles))
                ok = bool(inside.any())
            # one mesh's solid interior may hold another's surface (a nested mesh): surface wins
            grid[inside & (grid == FREE)] = SOLID
            grid[marked] = SURFACE
            closed.append(ok)
        return {"grid": grid, "lo": lo, "pitch": np.array(pitch), "closed": np.array(closed)}

    out, cached = load_or_build("shells", key, build, use_cache, {"grid": ((None, None, None), "u"),
                                                                 "lo": ((3,), "f"), "pitch": ((), "f"),
                                                                 "closed": ((len(heavy),), "b")})
    report = [{"name": s.name, "triangles": s.n_triangles, "closed": bool(c)} for s, c in zip(heavy, out["closed"])]
    return Shells(out["grid"], out["lo"], float(out["pitch"]), report, time.perf_counter() - t0, cached)


def overlaps(boxes, lo, hi):
    """Whether any of the boxes (n, 2, 3) overlaps the box [lo, hi]."""
    return bool(np.any(np.all((boxes[:, 0] <= hi) & (boxes[:, 1] >= lo), axis=1)))


class ShellArrays(NamedTuple):
    """`ShellTests` as the kernels take them (the BVH of the rest of the scene apart: `ShellTests.rest`)."""

    active: bool  # False: no shells, the other fields are placeholders never walked
    grid: np.ndarray  # (X, Y, Z) uint8 FREE, SURFACE or SOLID
    lo: np.ndarray  # (3,) the grid's corner
    pitch: float


@dataclass
class ShellTests:
    """What a kernel needs to decide segments by shells: whether there are any, the grid and the BVH of the rest
    of the scene (without its heavy meshes), which the segments the grid finds clear are tested against."""

    active: bool
    rest: object  # BVH
    grid: np.ndarray
    lo: np.ndarray
    pitch: float
    shells: Shells = None

    @property
    def arrays(self):
        return ShellArrays(self.active, self.grid, self.lo, self.pitch)

    @property
    def nbytes(self):
        """Bytes the shells add: the grid and the rest-of-scene BVH (none without shells)."""
        return self.grid.nbytes + self.rest.nbytes if self.active else 0

    def report(self):
        """The shells' description for the stats (None without shells)."""
        s = self.shells
        if s is None:
            return None
        return {"meshes": s.shapes, "grid": list(s.grid.shape), "voxel": s.pitch, "solid_voxels": s.solid_voxels,
                "surface_voxels": s.surface_voxels, "seconds": s.seconds, "cached": s.cached, "bytes": self.nbytes}

    @classmethod
    def none(cls, bvh):
        """No shells: the kernel's shell arguments as placeholders (never walked)."""
        return cls(False, bvh, np.zeros((1, 1, 1), np.uint8), np.zeros(3), 1.0)


def shell_memory(scene, min_triangles):
    """Bytes of the shells' structures, by part: the BVH of the scene without its heavy meshes (triangles and
    nodes, about 200 bytes a triangle) and the grid (a byte a voxel)."""
    heavy = sum(s.n_triangles for s in scene.shapes if s.n_triangles >= min_triangles and s.emitter < 0)
    if not heavy:
        return {}
    return {"shells: BVH of the scene without heavy meshes": (scene.n_triangles - heavy) * 200,
            "shells: voxel grid (RESOLUTION)": RESOLUTION ** 3}


def crossing_share(origin, direction, tmax, lo, hi):
    """Share of the segments origin + t direction, t in [0, tmax], that pass through the box [lo, hi] (slab
    tests; an axis the direction does not move along is crossed for all t or none)."""
    if len(origin) == 0:
        return 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / direction
        ta, tb = (lo - origin) * inv, (hi - origin) * inv
    near = np.fmax.reduce(np.fmin(ta, tb), axis=1)
    far = np.fmin.reduce(np.fmax(ta, tb), axis=1)
    return float(np.mean(np.maximum(near, 0.0) <= np.minimum(far, tmax)))


def shell_tests(scene, bvh, heavy, use_cache=True):
    """`ShellTests` for the scene's shapes `heavy` (`heavy_meshes`), or `ShellTests.none` when there are none."""
    from .accel import build_bvh

    shells = build_shells(scene, bvh, heavy, use_cache=use_cache)
    if shells is None:
        return ShellTests.none(bvh)
    keep = np.ones(scene.n_triangles, bool)
    for s in heavy:
        keep[s.first_triangle:s.first_triangle + s.n_triangles] = False
    # a BVH needs a triangle: a scene of heavy meshes alone gets a degenerate one, which nothing hits
    rest = scene.triangles[keep] if keep.any() else np.repeat(shells.lo[None, None], 3, axis=1)
    return ShellTests(True, build_bvh(rest), shells.grid, shells.lo, shells.pitch, shells)
