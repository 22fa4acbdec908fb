"""Photon pass: rays shot from the emitters, every surface crossing along each ray recorded.

The first hit of a photon ray is a light photon; each later hit is a shadow photon whose blockers are the
triangles hit before it on the same ray (visibility is geometric: every triangle blocks, whatever its
material or side). Rays are traced with an all-hits BVH query keeping the nearest `MAX_HITS` crossings;
crossings beyond that lie behind 15 blockers and are dropped.
"""
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from ...accel import all_hits
from ...geometry import unit_normal
from ...emitters import sample_on_emitter
from ...environment import sample_environment
from ...scene.scene import EMITTER_AREA, EMITTER_DIRECTIONAL, EMITTER_ENVIRONMENT, EMITTER_POINT, RAY_OFFSET
from ...parallel import over_threads
from ...rng import make_key, uniform

MAX_HITS = 16
PHOTON_STREAM = 0x5048  # rng stream of photon rays, apart from the camera's
ADAPTIVE_STREAM = 0x5049  # rng stream of the emitter points of adaptive photon rays
BATCH = 1 << 18  # photon rays per all-hits batch (bounds the (rays, MAX_HITS) scratch arrays)


class PhotonArrays(NamedTuple):
    """What the look-up kernels read of the photons."""

    normal: np.ndarray  # (p, 3)
    n_blockers: np.ndarray  # (p,) int32, 0 for light photons
    start: np.ndarray  # (p,) int64 into ray_tris
    ray_tris: np.ndarray  # int32


@dataclass
class Photons:
    """Flat photon arrays. Shadow photon i's blockers are `ray_tris[start[i]:start[i] + n_blockers[i]]`."""

    position: np.ndarray  # (p, 3)
    normal: np.ndarray  # (p, 3) face normal of the hit, turned towards where the photon came from
    emitter: np.ndarray  # (p,) int32
    n_blockers: np.ndarray  # (p,) int32, 0 for light photons
    start: np.ndarray  # (p,) int64 into ray_tris
    ray_tris: np.ndarray  # (rays * MAX_HITS,) int32, the hit triangles of each ray in order
    rays: int
    node_tests: int
    triangle_tests: int

    @property
    def shadow(self):
        return self.n_blockers > 0

    @property
    def arrays(self):
        return PhotonArrays(self.normal, self.n_blockers, self.start, self.ray_tris)

    def __len__(self):
        return len(self.emitter)

    @staticmethod
    def concatenate(parts):
        """One photon set from several passes (blocker ranges re-based onto the joint `ray_tris`)."""
        shift = np.cumsum([0] + [len(p.ray_tris) for p in parts[:-1]])
        return Photons(
            position=np.concatenate([p.position for p in parts]),
            normal=np.concatenate([p.normal for p in parts]),
            emitter=np.concatenate([p.emitter for p in parts]),
            n_blockers=np.concatenate([p.n_blockers for p in parts]),
            start=np.concatenate([p.start + s for p, s in zip(parts, shift)]),
            ray_tris=np.concatenate([p.ray_tris for p in parts]),
            rays=sum(p.rays for p in parts),
            node_tests=sum(p.node_tests for p in parts),
            triangle_tests=sum(p.triangle_tests for p in parts),
        )


def points_on_emitters(emitter, es, triangles, seed, stream, first):
    """Points uniform by area on the given emitters (`es` is the `EmitterArrays`; point i from
    rng key (seed, stream, first + i)), each nudged off its triangle along the front normal; returns points,
    unit front normals and the keys. Directional and environment light starts on a disk facing it beyond the
    scene's bounding sphere, its "normal" the direction it travels (an environment's by luminance)."""
    n = emitter.shape[0]
    out = (np.empty((n, 3)), np.empty((n, 3)), np.empty(n, np.uint64))
    over_threads(lambda _, lo, hi: _emitter_point_runs(emitter, es, triangles, (seed, stream, first), lo, hi, out), n)
    return out


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def _emitter_point_runs(emitter, es, triangles, stream_of, lo, hi, out):
    """Points lo..hi-1 of `points_on_emitters`, into `out`; `stream_of` is its (seed, stream, first)."""
    org, nrm, keys = out
    seed, stream, first = stream_of
    for i in range(lo, hi):
        key = make_key(seed, stream, first + i)
        keys[i] = key
        e = emitter[i]
        if es.kind[e] == EMITTER_DIRECTIONAL or es.kind[e] == EMITTER_ENVIRONMENT:
            r = es.sphere[3] * math.sqrt(uniform(key, 1))
            phi = 2.0 * math.pi * uniform(key, 2)
            ax, ay, az = es.axis[e, 0], es.axis[e, 1], es.axis[e, 2]
            if es.kind[e] == EMITTER_ENVIRONMENT:
                wx, wy, wz = sample_environment(es, uniform(key, 4), uniform(key, 5), uniform(key, 6))[:3]
                ax, ay, az = -wx, -wy, -wz
            tx, ty, tz, bx, by, bz = _basis(ax, ay, az)
            cu, su, far = r * math.cos(phi), r * math.sin(phi), 2.0 * es.sphere[3]
            org[i, 0] = es.sphere[0] - far * ax + cu * tx + su * bx
            org[i, 1] = es.sphere[1] - far * ay + cu * ty + su * by
            org[i, 2] = es.sphere[2] - far * az + cu * tz + su * bz
            nrm[i, 0], nrm[i, 1], nrm[i, 2] = ax, ay, az
            continue
        if es.kind[e] != EMITTER_AREA:  # a point or spot light: its position, its axis (a point's is unused)
            for c in range(3):
                org[i, c], nrm[i, c] = es.position[e, c], es.axis[e, c]
            continue
        t, x, y, z = sample_on_emitter(e, es, triangles, uniform(key, 1), uniform(key, 2), uniform(key, 3))
        nx, ny, nz = unit_normal(triangles, t)
        eps = RAY_OFFSET * (1.0 + max(abs(x), abs(y), abs(z)))
        org[i, 0], org[i, 1], org[i, 2] = x + eps * nx, y + eps * ny, z + eps * nz
        nrm[i, 0], nrm[i, 1], nrm[i, 2] = nx, ny, nz


def emission_directions(emitter, es, nrm, keys):
    """Per photon origin a direction (rng dimensions 4 and 5 of its key): cosine-distributed about the normal
    of an area emitter, uniform over the sphere for a point light and over the cutoff cone of a spot; directional
    and environment light keep the direction `points_on_emitters` gave."""
    dirs = np.empty((nrm.shape[0], 3))
    over_threads(lambda _, lo, hi: _direction_runs(emitter, es, nrm, keys, lo, hi, dirs), nrm.shape[0])
    return dirs


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def _direction_runs(emitter, es, nrm, keys, lo, hi, dirs):
    """Directions lo..hi-1 of `emission_directions`, into `dirs`."""
    for i in range(lo, hi):
        e = emitter[i]
        u1, u2 = uniform(keys[i], 4), uniform(keys[i], 5)
        if es.kind[e] == EMITTER_DIRECTIONAL or es.kind[e] == EMITTER_ENVIRONMENT:  # along the "normal"
            dirs[i, 0], dirs[i, 1], dirs[i, 2] = nrm[i, 0], nrm[i, 1], nrm[i, 2]
            continue
        if es.kind[e] == EMITTER_AREA:
            dirs[i, 0], dirs[i, 1], dirs[i, 2] = cosine_direction(nrm[i, 0], nrm[i, 1], nrm[i, 2], u1, u2)
            continue
        cos_lo = -1.0 if es.kind[e] == EMITTER_POINT else es.cone[e, 0]
        z = 1.0 - u1 * (1.0 - cos_lo)  # uniform in solid angle down to cos_lo about the axis
        r = math.sqrt(max(0.0, 1.0 - z * z))
        lx, ly = r * math.cos(2.0 * math.pi * u2), r * math.sin(2.0 * math.pi * u2)
        ax, ay, az = (0.0, 0.0, 1.0) if es.kind[e] == EMITTER_POINT else (es.axis[e, 0], es.axis[e, 1], es.axis[e, 2])
        tx, ty, tz, bx, by, bz = _basis(ax, ay, az)
        dirs[i, 0] = lx * tx + ly * bx + z * ax
        dirs[i, 1] = lx * ty + ly * by + z * ay
        dirs[i, 2] = lx * tz + ly * bz + z * az


@njit(cache=True, error_model="numpy", inline="always")
def _basis(ax, ay, az):
    """Two unit tangents completing the unit vector a to an orthonormal basis (Duff et al. 2017)."""
    sign = 1.0 if az >= 0.0 else -1.0
    a = -1.0 / (sign + az)
    b = ax * ay * a
    return 1.0 + sign * ax * ax * a, sign * b, -sign * ax, b, sign + ay * ay * a, -ay


@njit(cache=True, error_model="numpy", inline="always")
def cosine_direction(nx, ny, nz, u1, u2):
    """A direction about the unit normal n with density cos(theta) / pi (Malley's method)."""
    r = math.sqrt(u1)
    phi = 2.0 * math.pi * u2
    lx, ly = r * math.cos(phi), r * math.sin(phi)
    lz = math.sqrt(max(0.0, 1.0 - u1))
    # orthonormal basis of Duff et al. 2017
    sign = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    tx, ty, tz = 1.0 + sign * nx * nx * a, sign * b, -sign * nx
    bx, by, bz = b, sign + ny * ny * a, -ny
    return lx * tx + ly * bx + lz * nx, lx * ty + ly * by + lz * ny, lx * tz + ly * bz + lz * nz


def _photon_records(triangles, org, dirs, emitter, count, tri, dist):
    """Flatten the hits of a batch of photon rays into photons (see `Photons`)."""
    n = tri.shape[0]
    first = np.concatenate(([0], np.cumsum(count, dtype=np.int64)))
    p = int(first[n])
    out = (np.empty((p, 3)), np.empty((p, 3)), np.empty(p, np.int32), np.empty(p, np.int32), np.empty(p, np.int64))
    over_threads(lambda _, lo, hi: _record_runs(triangles, (org, dirs, emitter), (count, tri, dist), first, lo, hi,
                                                out), n)
    return out


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def _record_runs(triangles, rays, hits, first, lo, hi, out):
    """Photon rays lo..hi-1 of `_photon_records`: their hits' photons from position first[i] on, into `out`."""
    org, dirs, emitter = rays
    count, tri, dist = hits
    pos, nrm, emit, nb, start = out
    cap = tri.shape[1]
    for i in range(lo, hi):
        for h in range(count[i]):
            k = first[i] + h
            t = tri[i, h]
            for c in range(3):
                pos[k, c] = org[i, c] + dist[i, h] * dirs[i, c]
            nx, ny, nz = unit_normal(triangles, t)
            if nx * dirs[i, 0] + ny * dirs[i, 1] + nz * dirs[i, 2] > 0.0:
                nx, ny, nz = -nx, -ny, -nz
            nrm[k, 0], nrm[k, 1], nrm[k, 2] = nx, ny, nz
            emit[k] = emitter[i]
            nb[k] = h
            start[k] = i * cap


def trace_photons(scene, bvh, org, dirs, emitter):
    """All-hits trace of given photon rays (in batches), turned into a `Photons` set."""
    parts = []
    for b0 in range(0, len(org), BATCH):
        b1 = min(len(org), b0 + BATCH)
        count, tri, dist, n_node, n_tri = all_hits(bvh.arrays, org[b0:b1], dirs[b0:b1], np.zeros(b1 - b0),
                                                  MAX_HITS)
        pos, nrm, emit, nb, start = _photon_records(scene.triangles, org[b0:b1], dirs[b0:b1], emitter[b0:b1],
                                                    count, tri, dist)
        parts.append(Photons(pos, nrm, emit, nb, start, tri.reshape(-1), b1 - b0, int(n_node.sum()),
                             int(n_tri.sum())))
    if not parts:
        return Photons(np.empty((0, 3)), np.empty((0, 3)), np.empty(0, np.int32), np.empty(0, np.int32),
                       np.empty(0, np.int64), np.empty(0, np.int32), 0, 0, 0)
    return Photons.concatenate(parts)


def split_by_power(n, pmf):
    """Photon rays per emitter: `n` split in proportion to emitted power (largest remainders)."""
    share = n * pmf
    out = np.floor(share).astype(np.int64)
    out[np.argsort(out - share, kind="stable")[:n - out.sum()]] += 1
    return out


def shoot_photons(scene, bvh, emitters, n, seed):
    """`n` photon rays from the emitters, split by power."""
    emitter = np.repeat(np.arange(scene.n_emitters, dtype=np.int32), split_by_power(n, emitters.emitter_pmf))
    org, nrm, keys = points_on_emitters(emitter, emitters.arrays, scene.triangles, seed, PHOTON_STREAM, 0)
    return trace_photons(scene, bvh, org, emission_directions(emitter, emitters.arrays, nrm, keys), emitter)
