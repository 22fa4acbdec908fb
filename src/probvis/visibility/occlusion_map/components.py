"""Volumetric occluders: closed, consistently wound components of the scene's meshes.

A segment whose ends both lie outside a closed surface crosses it an even number of times, and if it
crosses at all it leaves the solid through a triangle whose outward side faces the segment's far end. So,
for visibility towards the light end, a closed component's triangles that face away from the light end never
need a ray-triangle test: only those facing it can be the first blocker found on an occluded segment.
"""
from typing import NamedTuple

import numpy as np

from ...disk_cache import content_key, load_or_build

CACHE_VERSION = 1  # bump when what `structure` derives changes


def components(scene):
    """Connected components of the scene's meshes: (label per triangle, merged vertex ids (n, 3), count).

    Vertices are merged where they coincide exactly within a shape (never across shapes); triangles are
    connected through shared vertices."""
    from scipy.sparse import coo_matrix  # imported where used: a render without lists never needs scipy
    from scipy.sparse.csgraph import connected_components

    n = scene.n_triangles
    shape_of = np.zeros(n, np.float64)
    for k, shape in enumerate(scene.shapes):
        shape_of[shape.first_triangle:shape.first_triangle + shape.n_triangles] = k
    keys = np.ascontiguousarray(np.column_stack([np.repeat(shape_of, 3), scene.triangles.reshape(-1, 3)]) + 0.0)
    _, vid = np.unique(keys.view(np.dtype((np.void, 32))).ravel(), return_inverse=True)  # + 0.0: no -0.0
    faces = vid.reshape(n, 3).astype(np.int64)
    n_v = int(vid.max()) + 1
    graph = coo_matrix((np.ones(2 * n), (np.concatenate([faces[:, 0], faces[:, 1]]),
                                         np.concatenate([faces[:, 1], faces[:, 2]]))), shape=(n_v, n_v))
    n_comp, vlabel = connected_components(graph, directed=False)
    return vlabel[faces[:, 0]], faces, n_comp


def closed_orientation(scene, comps=None):
    """Per scene triangle: +1 if it belongs to a closed component whose winding normals point outwards,
    -1 if they point inwards, 0 if its component is open or not consistently wound.

    Closed and consistent means every directed edge (a, b) of the component occurs exactly once and its
    reverse (b, a) exactly once; the sign of the enclosed volume gives the orientation.
    """
    label, faces, n_comp = components(scene) if comps is None else comps
    n_v = int(faces.max()) + 1
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    code = directed[:, 0] * n_v + directed[:, 1]
    reverse = directed[:, 1] * n_v + directed[:, 0]
    uniq, counts = np.unique(code, return_counts=True)
    once = counts == 1
    pos_r = np.minimum(np.searchsorted(uniq, reverse), len(uniq) - 1)
    good = once[np.searchsorted(uniq, code)] & (uniq[pos_r] == reverse) & once[pos_r]
    bad = np.bincount(np.tile(label, 3)[~good], minlength=n_comp) > 0
    small = np.bincount(label, minlength=n_comp) < 4
    v = scene.triangles
    volume = np.bincount(label, weights=np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])),
                         minlength=n_comp)
    sign = np.where(bad | small | (volume == 0.0), 0, np.sign(volume)).astype(np.int8)
    return sign[label]


class BlockerGroups(NamedTuple):
    """What each recorded blocker stands for in a candidate list: group `group[t]` of triangle t lists
    `tris[offsets[g]:offsets[g + 1]]`."""

    group: np.ndarray  # (triangles,) int32
    offsets: np.ndarray  # (groups + 1,) int64
    tris: np.ndarray  # int32 triangle ids, grouped

    @classmethod
    def singletons(cls, n_triangles):
        """Each triangle stands for itself."""
        return cls(np.arange(n_triangles, dtype=np.int32), np.arange(n_triangles + 1, dtype=np.int64),
                   np.arange(n_triangles, dtype=np.int32))


def blocker_groups(label, n_comp, max_size):
    """What a recorded blocker stands for in a candidate list (`BlockerGroups`): its whole connected component
    when that has at most `max_size` triangles (a box of a city, say), else itself."""
    n = len(label)
    size = np.bincount(label, minlength=n_comp)
    small = size[label] <= max_size
    # groups: small components keep their label; every other triangle gets a group of its own
    group = np.where(small, label, n_comp + np.arange(n)).astype(np.int64)
    used, group = np.unique(group, return_inverse=True)
    order = np.argsort(group, kind="stable").astype(np.int32)
    off = np.concatenate([[0], np.cumsum(np.bincount(group, minlength=len(used)))]).astype(np.int64)
    return BlockerGroups(group.astype(np.int32), off, order)


class Structure(NamedTuple):
    """What the occlusion map needs of the scene's connectivity: per triangle its component and orientation."""

    label: np.ndarray  # (triangles,) component of each triangle
    n_components: int
    orientation: np.ndarray  # (triangles,) int8, `closed_orientation`


def structure(scene, use_cache=True):
    """The scene's `Structure`, cached on disk by its triangles and shapes' spans (a tenth of a second on every
    render of a 70k-triangle mesh, a few milliseconds from the cache)."""
    spans = np.array([(s.first_triangle, s.n_triangles) for s in scene.shapes], np.int64).reshape(-1, 2)

    def build():
        comps = components(scene)
        return {"label": comps[0], "n_components": np.array(comps[2]),
                "orientation": closed_orientation(scene, comps)}

    key = content_key(f"occlusion map structure v{CACHE_VERSION}", scene.triangles, spans)
    n = scene.n_triangles
    out, _ = load_or_build("structure", key, build, use_cache, {"label": ((n,), "iu"), "n_components": ((), "iu"),
                                                                "orientation": ((n,), "i")})
    return Structure(out["label"], int(out["n_components"]), out["orientation"])
