"""Stage 1 of a render: primary rays of a Mitsuba perspective camera with a box pixel filter."""
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from .rng import make_key, uniform

STREAM_CAMERA = 1  # rng stream of camera paths


class CameraParams(NamedTuple):
    """A `scene.Camera` as the kernel takes it: half-extents of the image plane at distance 1."""

    to_world: np.ndarray
    tan_x: float
    tan_y: float
    width: int
    height: int
    near_clip: float
    far_clip: float


def camera_params(cam):
    """The kernel's `CameraParams` of a `scene.Camera`."""
    tan_x = float(np.tan(np.radians(cam.fov_x) / 2.0))
    return CameraParams(np.ascontiguousarray(cam.to_world, dtype=np.float64), tan_x, tan_x * cam.height / cam.width,
                        int(cam.width), int(cam.height), float(cam.near_clip), float(cam.far_clip))


@njit(cache=True, parallel=True, error_model="numpy")
def camera_rays(cam, spp, seed, pixel0, pixel1):
    """Rays for pixels [pixel0, pixel1) (row-major), `spp` per pixel, pixel-major order.

    Returns origins, unit directions, tmin, tmax and the rng key of each camera sample.
    """
    m, tan_x, tan_y, width, height, near, far = cam.to_world, cam.tan_x, cam.tan_y, cam.width, cam.height, \
        cam.near_clip, cam.far_clip
    n = (pixel1 - pixel0) * spp
    org = np.empty((n, 3))
    dirs = np.empty((n, 3))
    tmin = np.empty(n)
    tmax = np.empty(n)
    keys = np.empty(n, np.uint64)
    for i in prange(n):
        pix = pixel0 + i // spp
        s = i % spp
        key = make_key(seed, STREAM_CAMERA, pix * spp + s)
        px = pix % width
        py = pix // width
        sx = (px + uniform(key, 0)) / width
        sy = (py + uniform(key, 1)) / height
        lx = (1.0 - 2.0 * sx) * tan_x
        ly = (1.0 - 2.0 * sy) * tan_y
        inv_len = 1.0 / np.sqrt(lx * lx + ly * ly + 1.0)
        lx *= inv_len
        ly *= inv_len
        lz = inv_len
        wl = 0.0
        for j in range(3):
            dirs[i, j] = m[j, 0] * lx + m[j, 1] * ly + m[j, 2] * lz
            org[i, j] = m[j, 3]
            wl += dirs[i, j] * dirs[i, j]
        wl = np.sqrt(wl)
        for j in range(3):
            dirs[i, j] /= wl
        tmin[i] = near / lz * wl
        tmax[i] = far / lz * wl
        keys[i] = key
    return org, dirs, tmin, tmax, keys
