"""Triangle geometry shared by the kernels: unit face normals (winding order: counter-clockwise is front)."""
import math

import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy", inline="always")
def unit_normal(triangles, t):
    """Unit normal of triangle t of a (n, 3, 3) array, (v1 - v0) x (v2 - v0) normalised."""
    ax = triangles[t, 1, 0] - triangles[t, 0, 0]
    ay = triangles[t, 1, 1] - triangles[t, 0, 1]
    az = triangles[t, 1, 2] - triangles[t, 0, 2]
    bx = triangles[t, 2, 0] - triangles[t, 0, 0]
    by = triangles[t, 2, 1] - triangles[t, 0, 1]
    bz = triangles[t, 2, 2] - triangles[t, 0, 2]
    nx, ny, nz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    inv = 1.0 / math.sqrt(nx * nx + ny * ny + nz * nz)
    return nx * inv, ny * inv, nz * inv


@njit(cache=True, error_model="numpy")
def unit_normals(triangles):
    """(n, 3) `unit_normal` of every triangle, bit for bit as the kernels compute it."""
    out = np.empty((triangles.shape[0], 3))
    for t in range(triangles.shape[0]):
        out[t, 0], out[t, 1], out[t, 2] = unit_normal(triangles, t)
    return out
