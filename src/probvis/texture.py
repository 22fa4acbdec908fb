"""Reflectance textures as Mitsuba 3 evaluates them: `bitmap` (bilinear or nearest, repeat, mirror or clamp
wrapping, pixel centres at (i + 0.5) / size, v = 0 at the image's first row) and `checkerboard` (color0 where
both fractional uv coordinates are on the same side of 0.5), each through its `to_uv` affine map.

Textures are looked up once per camera hit, in the surface-interaction stage; the later stages only see the
point's albedo.
"""
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

BITMAP, CHECKERBOARD = 0, 1
REPEAT, MIRROR, CLAMP = 0, 1, 2
WRAP_MODES = {"repeat": REPEAT, "mirror": MIRROR, "clamp": CLAMP}


@dataclass
class Texture:
    """One texture: a linear-RGB `image` (h, w, 3) or, for a checkerboard, its two `colours` (2, 3)."""

    kind: int  # BITMAP or CHECKERBOARD
    to_uv: np.ndarray  # (2, 3) affine map of the surface's uv
    image: np.ndarray = None
    colours: np.ndarray = None
    wrap: int = REPEAT
    bilinear: bool = True

    def same_as(self, other):
        """Whether `other` looks up the same colours: the same settings over the same image (one decoded file is
        one array) or colours. Shapes that each name the same file share one texture."""
        return self is other or (self.kind == other.kind and self.wrap == other.wrap
                                 and self.bilinear == other.bilinear and np.array_equal(self.to_uv, other.to_uv)
                                 and self.image is other.image
                                 and (self.colours is other.colours or np.array_equal(self.colours, other.colours)))

    def mean(self):
        """Its mean colour (what appearance that cannot carry a texture falls back to)."""
        return self.image.reshape(-1, 3).mean(0) if self.kind == BITMAP else self.colours.mean(0)


class TextureArrays(NamedTuple):
    """All of a scene's textures as the kernels take them: texture t's pixels are data[offset[t]:offset[t + 1]]
    in rows of size[t, 0] (width)."""

    kind: np.ndarray  # (t,) int8
    wrap: np.ndarray  # (t,) int8
    bilinear: np.ndarray  # (t,) bool
    to_uv: np.ndarray  # (t, 2, 3)
    colours: np.ndarray  # (t, 2, 3) a checkerboard's colours
    size: np.ndarray  # (t, 2) width, height
    offset: np.ndarray  # (t + 1,)
    data: np.ndarray  # (pixels, 3)


def texture_arrays(textures):
    """`TextureArrays` of a list of `Texture` (an empty list gives one unused placeholder)."""
    textures = textures or [Texture(CHECKERBOARD, np.zeros((2, 3)), colours=np.zeros((2, 3)))]
    images = [t.image.reshape(-1, 3) if t.kind == BITMAP else np.zeros((0, 3)) for t in textures]
    return TextureArrays(
        np.array([t.kind for t in textures], np.int8), np.array([t.wrap for t in textures], np.int8),
        np.array([t.bilinear for t in textures], np.bool_), np.array([t.to_uv for t in textures], np.float64),
        np.array([t.colours if t.colours is not None else np.zeros((2, 3)) for t in textures], np.float64),
        np.array([t.image.shape[1::-1] if t.kind == BITMAP else (0, 0) for t in textures], np.int64),
        np.concatenate([[0], np.cumsum([len(i) for i in images])]).astype(np.int64),
        np.ascontiguousarray(np.concatenate(images), dtype=np.float64))


@njit(cache=True, error_model="numpy", inline="always")
def _wrap(i, n, mode):
    if mode == CLAMP:
        return min(max(i, 0), n - 1)
    if mode == MIRROR:
        i %= 2 * n
        return i if i < n else 2 * n - 1 - i
    return i % n


@njit(cache=True, error_model="numpy", inline="always")
def _texel(tx, t, x, y):
    """Row of `tx.data` holding texel (x, y) of texture t, wrapped as the texture says."""
    w, h = tx.size[t, 0], tx.size[t, 1]
    return tx.offset[t] + _wrap(y, h, tx.wrap[t]) * w + _wrap(x, w, tx.wrap[t])


@njit(cache=True, error_model="numpy")
def texture_value(tx, t, u, v):
    """Texture t of `tx` (`TextureArrays`) at surface coordinates (u, v): (r, g, b)."""
    a = tx.to_uv[t]
    uu = a[0, 0] * u + a[0, 1] * v + a[0, 2]
    vv = a[1, 0] * u + a[1, 1] * v + a[1, 2]
    if tx.kind[t] == CHECKERBOARD:
        k = 0 if ((uu - math.floor(uu)) > 0.5) == ((vv - math.floor(vv)) > 0.5) else 1
        return tx.colours[t, k, 0], tx.colours[t, k, 1], tx.colours[t, k, 2]
    w, h = tx.size[t, 0], tx.size[t, 1]
    if not tx.bilinear[t]:
        k = _texel(tx, t, int(math.floor(uu * w)), int(math.floor(vv * h)))
        return tx.data[k, 0], tx.data[k, 1], tx.data[k, 2]
    fx, fy = uu * w - 0.5, vv * h - 0.5
    x0, y0 = math.floor(fx), math.floor(fy)
    wx, wy = fx - x0, fy - y0
    x, y = int(x0), int(y0)
    k00, k10 = _texel(tx, t, x, y), _texel(tx, t, x + 1, y)
    k01, k11 = _texel(tx, t, x, y + 1), _texel(tx, t, x + 1, y + 1)
    d = tx.data
    return (_bilinear(d, k00, k10, k01, k11, wx, wy, 0), _bilinear(d, k00, k10, k01, k11, wx, wy, 1),
            _bilinear(d, k00, k10, k01, k11, wx, wy, 2))


@njit(cache=True, error_model="numpy", inline="always")
def _bilinear(d, k00, k10, k01, k11, wx, wy, c):
    """Channel c of the bilinear blend of texel rows k00, k10 (x + 1), k01 (y + 1), k11 with weights (wx, wy)."""
    top = (1.0 - wx) * d[k00, c] + wx * d[k10, c]
    bottom = (1.0 - wx) * d[k01, c] + wx * d[k11, c]
    return (1.0 - wy) * top + wy * bottom
