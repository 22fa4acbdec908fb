"""Conservative shells around and inside heavy meshes: visibility decided exactly, with no variance, for the
segments they apply to (the bounding and inner envelopes of Cohen et al.'s simplification envelopes, built on
a voxel grid rather than by offsetting, because a grid is conservative by construction).

On a grid of `resolution` voxels along the longest side of the heavy meshes' bounds, every voxel that a heavy
triangle's bounding box touches (padded) is marked. The unmarked voxels split into 6-connected regions; each
contains no surface, so it lies wholly inside or wholly outside every mesh. A region not touching the grid's
border is inside a watertight mesh when rays from its voxels cross that mesh an odd number of times (three
rays from three voxels, all odd). Then:

- the **inner shell** (the boundary of the inside regions, as triangles) lies strictly inside closed meshes: a
  segment that crosses it passes through a mesh's solid interior, so it crosses the mesh and is blocked
  (its ends are outside the mesh: a closed mesh with an emitter in its bounds gets no inner shell);
- the **outer shell** (the boundary of the marked and inside voxels) contains every heavy mesh: a segment that
  neither crosses it nor starts inside it (an O(1) lookup in the grid) cannot meet a heavy mesh, so only the
  rest of the scene can block it.

Both shells are few triangles: each boundary is merged greedily into rectangles, slice by slice. They are
cached on disk (`disk_cache`) keyed by the heavy meshes, the emitters and the resolution.
"""
import time
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy import ndimage

from .disk_cache import content_key, load_or_build
from .proxies import weld
from .scene.scene import EMITTER_POINT, EMITTER_SPOT

RESOLUTION = 64  # voxels along the longest side of the heavy meshes' bounds
PAD = 1e-3  # triangle bounds are padded by this fraction of a voxel: a segment leaving a heavy mesh starts inside
PARITY_CAP = 4096  # hits counted per parity ray; a ray that reaches it decides nothing
PARITY_DIRECTIONS = np.array([[0.5773, 0.5774, 0.5773], [-0.6402, 0.3197, 0.6985], [0.2113, -0.8660, 0.4531]])
CACHE_VERSION = 1


@dataclass
class Shells:
    """The inner and outer shell triangles, the outer shell's voxel grid (for "starts inside") and which shapes
    they cover."""

    inner: np.ndarray  # (i, 3, 3): crossing it means blocked
    outer: np.ndarray  # (o, 3, 3): missing it (and starting outside `grid`) means no heavy mesh in the way
    grid: np.ndarray  # (X, Y, Z) uint8: 1 for voxels inside the outer shell
    lo: np.ndarray  # (3,) the grid's corner
    pitch: float  # its voxel size
    shapes: list  # dicts: name, triangles, closed (has an inner shell)
    seconds: float = 0.0
    cached: bool = False


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


@njit(cache=True)
def _face_rectangles(occ):
    """Rectangles covering the faces between occupied and empty voxels across the first axis of `occ` (padded
    with empty voxels all round), merged greedily per slice: rows of (slice, r0, c0, r1, c1)."""
    n0, n1, n2 = occ.shape
    out = np.empty((16, 5), np.int64)
    n = 0
    used = np.zeros((n1, n2), np.bool_)
    mask = np.zeros((n1, n2), np.bool_)
    for s in range(n0 - 1):
        for sign in range(2):
            for r in range(n1):
                for c in range(n2):
                    a, b = occ[s, r, c], occ[s + 1, r, c]
                    mask[r, c] = a and not b if sign == 0 else b and not a
                    used[r, c] = False
            for r in range(n1):
                for c in range(n2):
                    if not mask[r, c] or used[r, c]:
                        continue
                    c1 = c
                    while c1 + 1 < n2 and mask[r, c1 + 1] and not used[r, c1 + 1]:
                        c1 += 1
                    r1 = r
                    grow = True
                    while grow and r1 + 1 < n1:
                        for cc in range(c, c1 + 1):
                            if not mask[r1 + 1, cc] or used[r1 + 1, cc]:
                                grow = False
                                break
                        if grow:
                            r1 += 1
                    used[r:r1 + 1, c:c1 + 1] = True
                    if n == out.shape[0]:
                        bigger = np.empty((2 * n, 5), np.int64)
                        bigger[:n] = out
                        out = bigger
                    out[n, 0], out[n, 1], out[n, 2], out[n, 3], out[n, 4] = s, r, c, r1, c1
                    n += 1
    return out[:n]


def boundary_triangles(occ, lo, pitch):
    """The boundary of a voxel set as triangles (two per merged rectangle), in world coordinates."""
    padded = np.pad(occ, 1)
    quads = []
    for axis in range(3):
        rect = _face_rectangles(np.ascontiguousarray(np.moveaxis(padded, axis, 0)))
        others = [a for a in range(3) if a != axis]
        # padded voxel i is grid voxel i-1: a face between padded slices s and s+1 lies at grid coordinate s, and
        # rectangle cells r0..r1 (padded) span grid coordinates r0-1 .. r1
        corners = np.zeros((len(rect), 4, 3))
        corners[:, :, axis] = rect[:, 0, None]
        r0, c0, r1, c1 = rect[:, 1] - 1, rect[:, 2] - 1, rect[:, 3], rect[:, 4]
        for k, (r, c) in enumerate(((r0, c0), (r1, c0), (r1, c1), (r0, c1))):
            corners[:, k, others[0]] = r
            corners[:, k, others[1]] = c
        quads.append(corners)
    q = lo + pitch * np.concatenate(quads)
    return np.ascontiguousarray(np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]]))


def is_closed(tris):
    """Whether a triangle soup, its equal corners welded, is watertight: every edge shared by exactly two
    triangles."""
    vertices, faces = weld(tris)
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges[:, 0] * len(vertices) + edges[:, 1], return_counts=True)
    return bool(len(faces)) and bool(np.all(counts == 2))


def _inside_regions(labels, n_labels, lo, pitch, bvh, first, count):
    """Labels of the empty regions (`labels` of the unmarked voxels) inside the mesh of scene triangles
    first..first+count: not touching the grid's border, and every parity ray from three of their voxels crosses
    it an odd number of times."""
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


def build_shells(scene, bvh, min_triangles, resolution=RESOLUTION, use_cache=True):
    """`Shells` of the scene's shapes of at least `min_triangles` triangles (not emitters), or None when there
    are none."""
    t0 = time.perf_counter()
    heavy = [s for s in scene.shapes if s.n_triangles >= min_triangles and s.emitter < 0]
    if not heavy:
        return None
    spans = [scene.triangles[s.first_triangle:s.first_triangle + s.n_triangles] for s in heavy]
    emitter_boxes = np.array([[scene.triangles[s.first_triangle:s.first_triangle + s.n_triangles].min((0, 1)),
                               scene.triangles[s.first_triangle:s.first_triangle + s.n_triangles].max((0, 1))]
                              for s in scene.shapes if s.emitter >= 0]).reshape(-1, 2, 3)
    points = scene.emitter_position[np.isin(scene.emitter_kind, (EMITTER_POINT, EMITTER_SPOT))]
    emitter_boxes = np.concatenate([emitter_boxes, np.stack([points, points], axis=1)])
    key = content_key(f"shells v{CACHE_VERSION} resolution {resolution}", emitter_boxes, *spans)

    def build():
        lo = np.min([t.min((0, 1)) for t in spans], axis=0)
        hi = np.max([t.max((0, 1)) for t in spans], axis=0)
        pitch = float((hi - lo).max()) / (resolution - 2)
        lo = lo - pitch  # a free voxel layer all round: the border region is outside
        dims = np.maximum(np.ceil((hi - lo) / pitch).astype(np.int64) + 2, 3)
        outer = np.zeros(dims, bool)
        inner = np.zeros(dims, bool)
        closed = []
        for shape, tris in zip(heavy, spans):
            marked = np.zeros(dims, bool)
            _mark(tris, lo, pitch, PAD * pitch, dims, marked)
            outer |= marked
            ok = is_closed(tris) and not _emitter_within(emitter_boxes, tris)
            if ok:
                labels, n_labels = ndimage.label(~marked)
                inside = np.isin(labels, _inside_regions(labels, n_labels, lo, pitch, bvh,
                                                         shape.first_triangle, shape.n_triangles))
                inner |= inside
                outer |= inside
                ok = bool(inside.any())
            closed.append(ok)
        return {"inner": boundary_triangles(inner, lo, pitch).reshape(-1, 3, 3),
                "outer": boundary_triangles(outer, lo, pitch).reshape(-1, 3, 3),
                "grid": outer.astype(np.uint8), "lo": lo, "pitch": np.array(pitch), "closed": np.array(closed)}

    out, cached = load_or_build("shells", key, build, use_cache)
    report = [{"name": s.name, "triangles": s.n_triangles, "closed": bool(c)} for s, c in zip(heavy, out["closed"])]
    return Shells(out["inner"], out["outer"], out["grid"], out["lo"], float(out["pitch"]), report,
                  time.perf_counter() - t0, cached)


def _emitter_within(boxes, tris):
    """Whether any emitter's bounds overlap the bounds of `tris`."""
    lo, hi = tris.min((0, 1)), tris.max((0, 1))
    return bool(np.any(np.all((boxes[:, 0] <= hi) & (boxes[:, 1] >= lo), axis=1)))


@dataclass
class ShellTests:
    """What the fused kernel needs to test segments against shells: which shells apply (bit 1 inner, bit 2
    outer), their BVHs, the BVH of the rest of the scene and the outer shell's grid."""

    flags: int
    inner: object  # BVH
    outer: object
    rest: object
    grid: np.ndarray
    lo: np.ndarray
    pitch: float
    shells: Shells = None

    @property
    def kernel_args(self):
        return (self.flags, self.inner.arrays, self.outer.arrays, self.rest.arrays, self.grid, self.lo, self.pitch)

    @classmethod
    def none(cls, bvh):
        """No shells: the kernel's shell arguments as placeholders (never traced)."""
        return cls(0, bvh, bvh, bvh, np.zeros((1, 1, 1), np.uint8), np.zeros(3), 1.0)


def shell_memory(scene, min_triangles):
    """Bytes of the shells' structures, by part: the BVH of the scene without its heavy meshes (triangles and
    nodes, about 200 bytes a triangle), the grid and the shells' own BVHs (at most a few of the grid's faces)."""
    heavy = sum(s.n_triangles for s in scene.shapes if s.n_triangles >= min_triangles and s.emitter < 0)
    if not heavy:
        return {}
    return {"shells: BVH of the scene without heavy meshes": (scene.n_triangles - heavy) * 200,
            "shells: voxel grid and shell BVHs (RESOLUTION)": RESOLUTION ** 3 * 16 + 12 * RESOLUTION ** 2 * 2 * 200}


def shell_tests(scene, bvh, min_triangles, use_cache=True):
    """`ShellTests` for the scene's heavy meshes (`build_shells`), or `ShellTests.none` when it has none."""
    from .accel import build_bvh

    shells = build_shells(scene, bvh, min_triangles, use_cache=use_cache)
    if shells is None:
        return ShellTests.none(bvh)
    keep = np.ones(scene.n_triangles, bool)
    for s in scene.shapes:
        if s.n_triangles >= min_triangles and s.emitter < 0:
            keep[s.first_triangle:s.first_triangle + s.n_triangles] = False
    # a BVH needs a triangle: a scene of heavy meshes alone gets a degenerate one, which nothing hits
    rest = scene.triangles[keep] if keep.any() else np.repeat(shells.lo[None, None], 3, axis=1)
    outer = build_bvh(shells.outer)
    inner = build_bvh(shells.inner) if len(shells.inner) else outer
    flags = (1 if len(shells.inner) else 0) | 2
    return ShellTests(flags, inner, outer, build_bvh(rest), shells.grid, shells.lo, shells.pitch, shells)
