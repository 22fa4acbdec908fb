"""The occlusion map: photons of each emitter in a kd-tree, looked up in batches to classify shading points."""
from dataclasses import dataclass

import numba
import numpy as np

from .lookup import classify_points
from .photons import MAX_HITS, Photons

NORMAL_COS = 0.7  # a photon counts for a shading point when their normals are within ~45 degrees
MIN_PHOTONS = 4  # fewer agreeing photons than this leave a point unknown (tested against the whole scene)
RADIUS_SCALE = 2.0  # automatic radius: this times the median distance from a photon to its k-th neighbour
CELL_FRACTION = 0.25  # shading points in one cell of this fraction of the radius, with one normal, share a look-up


@dataclass
class Lookup:
    """Classification of m shading points against each emitter's photons.

    Points are looked up through representatives: point i uses look-up `rep[i]`, made at point `first[rep[i]]`,
    of the `n_rep` made. `case[i, e]` is a CASE_*; the candidate list of (i, e) is `tris[lo:hi]` with
    (lo, hi) = `range(i, e)`; `neighbours[e]` the (n_rep, k) photon ids found (-1 for none).
    """

    case: np.ndarray
    rep: np.ndarray
    first: np.ndarray
    offsets: np.ndarray
    tris: np.ndarray
    neighbours: list
    photons: np.ndarray  # (n_rep, emitters, 2) agreeing light and shadow photons of each look-up
    unseen: np.ndarray  # (n_rep, emitters) Good-Turing share of blockers the list has not seen (penumbra, lists)

    @property
    def n_rep(self):
        return len(self.first)

    def range(self, i, e):
        pair = np.asarray(e, np.int64) * self.n_rep + self.rep[i]
        return self.offsets[pair], self.offsets[pair + 1]

    def candidates(self, i, e):
        lo, hi = self.range(i, e)
        return self.tris[lo:hi]


class OcclusionMap:
    """Photons of each emitter in a `scipy.spatial.cKDTree`; `radius=None` picks one from the photon density.

    `groups` (`BlockerGroups`) says what a recorded blocker stands for in a candidate list (see
    `components.blocker_groups`)."""

    def __init__(self, photons: Photons, n_emitters, neighbours, groups, radius=None):
        self.photons = photons
        self.groups = groups
        self.n_emitters = n_emitters
        self.k = int(neighbours)
        self.ids = [np.flatnonzero(photons.emitter == e) for e in range(n_emitters)]
        # sliding-midpoint splits without shrunk boxes: built in less than half the time of scipy's default
        # (median splits), queries as fast; only ties in distance (photons at one position) may resolve differently
        from scipy.spatial import cKDTree  # imported where used: scipy takes 0.2 s to import

        self.trees = [cKDTree(photons.position[ids], balanced_tree=False, compact_nodes=False) if len(ids) else None
                      for ids in self.ids]
        self.radius = float(radius) if radius is not None else self._auto_radius()

    def _auto_radius(self):
        dists = []
        rng = np.random.default_rng(0)
        for ids, tree in zip(self.ids, self.trees):
            if tree is None or len(ids) <= 1:
                continue
            probe = self.photons.position[ids[rng.choice(len(ids), min(len(ids), 4096), replace=False)]]
            # a probe is a photon of the tree: with one neighbour its nearest would be itself, at 0
            d, _ = tree.query(probe, k=min(max(self.k, 2), len(ids)), workers=numba.get_num_threads())
            dists.append(d.reshape(len(probe), -1)[:, -1])
        if not dists:
            return 1.0
        d = np.concatenate(dists)
        typical = float(np.median(d))  # 0 only where most probes share their place with another photon
        return RADIUS_SCALE * (typical if typical > 0 else float(d.max()) or 1.0)

    def neighbours(self, pos, e, k=None):
        """(m, k) ids of emitter e's photons nearest to each position within the radius, -1 where none."""
        k = self.k if k is None else k
        tree = self.trees[e]
        if tree is None or len(pos) == 0:
            return np.full((len(pos), k), -1, np.int64)
        _, idx = tree.query(pos, k=k, distance_upper_bound=self.radius, workers=numba.get_num_threads())
        idx = idx.reshape(len(pos), k)
        lookup = np.append(self.ids[e], -1)
        return lookup[np.minimum(idx, len(self.ids[e]))]

    def representatives(self, pos, nrm, cell):
        """Points sharing a cell of side `cell` and a normal rounded to a 5 x 5 x 5 lattice share one look-up:
        (index of each point's representative, indices of the representatives)."""
        key = np.column_stack([np.floor(pos / cell), np.round(nrm * 2.0)]).astype(np.int64)
        if len(key) == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        lo = key.min(axis=0)
        span = key.max(axis=0) - lo + 1
        if np.prod([int(x) for x in span]) < 1 << 62:  # one int64 per point: sorted four times faster than rows
            packed = np.zeros(len(key), np.int64)
            for c in range(key.shape[1]):
                packed = packed * span[c] + (key[:, c] - lo[c])
        else:
            packed = np.ascontiguousarray(key).view(np.dtype((np.void, key.shape[1] * 8))).ravel()
        _, first, rep = np.unique(packed, return_index=True, return_inverse=True)
        return rep.ravel(), first

    def lookup(self, pos, nrm, share=True, with_lists=True):
        """Classify points with positions `pos` and normals `nrm` (zero for points not shaded); with `share`,
        nearby points with like normals share a look-up (see `representatives`); `with_lists=False` skips the
        candidate lists."""
        if share and len(pos):
            rep, first = self.representatives(pos, nrm, CELL_FRACTION * self.radius)
        else:
            rep, first = np.arange(len(pos)), np.arange(len(pos))
        pos, nrm = pos[first], nrm[first]
        m = len(pos)
        p = self.photons
        case = np.empty((m, self.n_emitters), np.int8)
        counts = np.empty((m, self.n_emitters, 2), np.int32)
        unseen = np.zeros((m, self.n_emitters))
        offs, tris, nbrs = [np.zeros(1, np.int64)], [], []
        for e in range(self.n_emitters):
            nbr = self.neighbours(pos, e)
            c, o, t, counts[:, e], unseen[:, e] = classify_points(nbr, nrm, p.arrays, self.groups, NORMAL_COS,
                                                                  MIN_PHOTONS, MAX_HITS, with_lists)
            case[:, e] = c
            offs.append(o[1:] + offs[-1][-1])
            tris.append(t)
            nbrs.append(nbr)
        return Lookup(case[rep], rep, first, np.concatenate(offs), np.concatenate(tris), nbrs, counts, unseen)
