"""Classification of shading points from their neighbouring photons, and their candidate blocker lists.

For one emitter, the photons near a shading point whose normals agree with its own decide its case: only light
photons - lit; only shadow photons - shadowed; both - penumbra, whose candidate list is the union of the
neighbouring shadow photons' blockers, most frequently recorded first. Fewer than `min_photons` agreeing
photons leaves the point unknown (sampled and tested against the whole scene: unbiased, just not faster).

Blockers are gathered as *groups*: `group[t]` names the set of triangles a recorded triangle t stands for
(its whole small connected component, or t alone) and `group_tris[group_off[g]:group_off[g + 1]]` lists it.
"""
import numpy as np
from numba import njit

from ...cases import CASE_LIT, CASE_PENUMBRA, CASE_SHADOWED, CASE_UNKNOWN
from ...parallel import over_threads


@njit(cache=True, error_model="numpy", inline="always")
def _gather(nbr, i, pn, nb, start, ray_tris, group, nx, ny, nz, normal_cos, buf):
    """Blocker groups of point i's agreeing shadow photons into `buf`; returns (light, shadow, gathered)."""
    n_light, n_shadow, m = 0, 0, 0
    for k in range(nbr.shape[1]):
        j = nbr[i, k]
        if j < 0 or pn[j, 0] * nx + pn[j, 1] * ny + pn[j, 2] * nz < normal_cos:
            continue
        if nb[j] == 0:
            n_light += 1
        else:
            n_shadow += 1
            for h in range(nb[j]):
                buf[m] = group[ray_tris[start[j] + h]]
                m += 1
    return n_light, n_shadow, m


RANKED = 64  # lists of up to this many blocker groups are ordered by branch-free comparisons, longer ones sorted


@njit(cache=True, error_model="numpy", inline="always")
def _by_frequency(buf, m, seen, scratch, out):
    """Distinct values of buf[:m] into out[:u], most frequent first (ties: lower id first); returns u and how
    many occur once. `seen` is a table of zeros indexed by value (left zero), `scratch` (ids, counts) of m
    entries or more."""
    ids, cnt = scratch
    u = 0
    for a in range(m):
        v = buf[a]
        if seen[v] == 0:
            ids[u] = v
            u += 1
        seen[v] += 1
    singles = 0
    for a in range(u):
        cnt[a] = seen[ids[a]]
        seen[ids[a]] = 0
        singles += cnt[a] == 1
    if u <= RANKED:  # each one's place: the values before it, counted (a sort's comparisons mispredict)
        for a in range(u):
            ca, ia = cnt[a], ids[a]
            r = 0
            for b in range(u):
                r += (cnt[b] > ca) | ((cnt[b] == ca) & (ids[b] < ia))
            out[r] = ia
    else:
        key = np.empty(u, np.int64)
        for a in range(u):
            key[a] = (np.int64(m) - cnt[a]) * np.int64(1 << 31) + ids[a]
        order = np.argsort(key)
        for a in range(u):
            out[a] = ids[order[a]]
    return u, singles


def classify_points(nbr, nrm, photons, groups, normal_cos, min_photons, max_hits, with_lists):
    """Case, candidate list (CSR of triangles, most often recorded groups first), agreeing (light, shadow)
    photon counts and, for penumbra points with lists, the Good-Turing estimate of the list's unseen blockers
    (the share of recorded blockers recorded only once: the chance that the next shadow photon would record a
    blocker not in the list) per point.

    `nbr` (m, k) holds photon ids of one emitter's photons near each point (-1 for none); `nrm` the points'
    normals (a zero normal marks a point that is not shaded); `photons` the `PhotonArrays`, `groups` the
    `BlockerGroups`. Without `with_lists` the lists are left empty. Two serial kernels run over the thread
    budget (`over_threads`): the cases and each list's groups, then the lists' triangles.
    """
    m, k = nbr.shape
    case = np.full(m, CASE_UNKNOWN, np.int8)
    counts = np.zeros((m, 2), np.int32)
    unseen = np.zeros(m)
    length = np.zeros(m + 1, np.int64)
    # each penumbra point's distinct blocker groups, most frequent first (pages are touched only where written)
    found = np.empty((m if with_lists else 0, k * max_hits), np.int32)
    n_found = np.zeros(m, np.int64)
    out = (case, counts, unseen, length, found, n_found)
    n_chunks = (m + 63) // 64
    over_threads(lambda _, first, end: _classify_chunks(nbr, nrm, photons, groups.group, groups.offsets, normal_cos,
                                                        min_photons, with_lists, first, end, out,
                                                        np.empty(k * max_hits, np.int32)), n_chunks)
    offsets = np.cumsum(length)
    tris = np.empty(offsets[m], np.int32)
    if with_lists:
        over_threads(lambda _, first, end: _list_chunks(found, n_found, offsets, groups.offsets, groups.tris, first,
                                                        end, tris), n_chunks)
    return case, offsets, tris, counts, unseen


@njit(cache=True, nogil=True, error_model="numpy")
def _classify_chunks(nbr, nrm, photons, group, group_off, normal_cos, min_photons, with_lists, first, end, out, buf):
    """Chunks first..end-1 (64 points each) of `classify_points`' cases, counts, unseen shares, list lengths and
    groups found, into `out`; `buf` is this thread's scratch."""
    pn, nb, start, ray_tris = photons.normal, photons.n_blockers, photons.start, photons.ray_tris
    case, counts, unseen, length, found, n_found = out
    m = nbr.shape[0]
    scratch = (np.empty(buf.shape[0], np.int32), np.empty(buf.shape[0], np.int32))
    seen = np.zeros(group_off.shape[0] - 1 if with_lists else 0, np.int32)
    for c in range(first, end):
        for i in range(c * 64, min(m, c * 64 + 64)):
            nx, ny, nz = nrm[i, 0], nrm[i, 1], nrm[i, 2]
            if nx == 0.0 and ny == 0.0 and nz == 0.0:
                continue
            n_light, n_shadow, g = _gather(nbr, i, pn, nb, start, ray_tris, group, nx, ny, nz, normal_cos, buf)
            counts[i, 0], counts[i, 1] = n_light, n_shadow
            if n_light + n_shadow < min_photons:
                continue
            if n_shadow == 0:
                case[i] = CASE_LIT
            elif n_light == 0:
                case[i] = CASE_SHADOWED
            else:
                case[i] = CASE_PENUMBRA
                if not with_lists:
                    continue
                u, singles = _by_frequency(buf, g, seen, scratch, found[i])
                n_found[i] = u
                for a in range(u):
                    gr = found[i, a]
                    length[i + 1] += group_off[gr + 1] - group_off[gr]
                unseen[i] = singles / max(g, 1)


@njit(cache=True, nogil=True, _nrt=False, error_model="numpy")
def _list_chunks(found, n_found, offsets, group_off, group_tris, first, end, tris):
    """Chunks first..end-1 of `classify_points`' lists: each point's groups' triangles, in the groups' order."""
    m = n_found.shape[0]
    for c in range(first, end):
        for i in range(c * 64, min(m, c * 64 + 64)):
            w = offsets[i]
            for a in range(n_found[i]):
                gr = found[i, a]
                for h in range(group_off[gr], group_off[gr + 1]):
                    tris[w] = group_tris[h]
                    w += 1
