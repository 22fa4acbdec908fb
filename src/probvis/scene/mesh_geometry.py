"""The geometry of a triangle mesh as the scene builder needs it: each face's corners, normal and area (and
whether it has any), and vertex normals weighted by the faces' angles at the vertex, as Mitsuba computes them."""
import math

import numpy as np
from numba import njit, prange


@njit(cache=True, parallel=True, error_model="numpy")
def face_geometry(wv, f):
    """Each face's corners (n, 3, 3), the cross product of its edges from the first corner, that product's
    length (twice its area) and whether the face has area: one pass, no temporaries (numpy's `wv[f]`, `np.cross`
    and `norm` made five), the faces split over the threads.

    A face has area when twice its area exceeds 1e-14 times its longest edge squared (a sliver thinner than that
    has no normal to speak of): a measure of its own shape, wherever it lies (a small object far from the origin,
    or beside a far vertex of its file, keeps its faces)."""
    n = f.shape[0]
    tris, cross, area2, keep = np.empty((n, 3, 3)), np.empty((n, 3)), np.empty(n), np.empty(n, np.bool_)
    for i in prange(n):
        for c in range(3):
            for d in range(3):
                tris[i, c, d] = wv[f[i, c], d]
        ax, ay, az = tris[i, 1, 0] - tris[i, 0, 0], tris[i, 1, 1] - tris[i, 0, 1], tris[i, 1, 2] - tris[i, 0, 2]
        bx, by, bz = tris[i, 2, 0] - tris[i, 0, 0], tris[i, 2, 1] - tris[i, 0, 1], tris[i, 2, 2] - tris[i, 0, 2]
        cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        cross[i, 0], cross[i, 1], cross[i, 2] = cx, cy, cz
        area2[i] = math.sqrt(cx * cx + cy * cy + cz * cz)
        ex, ey, ez = bx - ax, by - ay, bz - az
        longest = max(ax * ax + ay * ay + az * az, bx * bx + by * by + bz * bz, ex * ex + ey * ey + ez * ez)
        keep[i] = area2[i] > 1e-14 * longest
    return tris, cross, area2, keep


@njit(cache=True, parallel=True, error_model="numpy")
def _corner_angles(v, f):
    """Each face corner's angle (faces, 3), the faces split over the threads."""
    ang = np.empty((f.shape[0], 3))
    for i in prange(f.shape[0]):
        for k in range(3):
            a, b, c = f[i, k], f[i, (k + 1) % 3], f[i, (k + 2) % 3]
            e1x, e1y, e1z = v[b, 0] - v[a, 0], v[b, 1] - v[a, 1], v[b, 2] - v[a, 2]
            e2x, e2y, e2z = v[c, 0] - v[a, 0], v[c, 1] - v[a, 1], v[c, 2] - v[a, 2]
            cosang = (e1x * e2x + e1y * e2y + e1z * e2z) / (math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z) *
                                                             math.sqrt(e2x * e2x + e2y * e2y + e2z * e2z))
            ang[i, k] = math.acos(min(max(cosang, -1.0), 1.0))
    return ang


@njit(cache=True, error_model="numpy")
def angle_weighted_normals(v, f, fn):
    """Vertex normals as the corner-angle-weighted mean of the adjacent face normals (unit; zero where a
    vertex has no face). The corners' angles in parallel, then each corner added to its vertex in a fixed
    order (corner 0 of every face, then 1, then 2), so the sums do not depend on the thread count."""
    ang = _corner_angles(v, f)
    out = np.zeros_like(v)
    for k in range(3):
        for i in range(f.shape[0]):
            a = f[i, k]
            for d in range(3):
                out[a, d] += fn[i, d] * ang[i, k]
    for j in range(out.shape[0]):
        norm = math.sqrt(out[j, 0] * out[j, 0] + out[j, 1] * out[j, 1] + out[j, 2] * out[j, 2])
        for d in range(3):
            out[j, d] = out[j, d] / norm if norm > 0 else 0.0
    return out
