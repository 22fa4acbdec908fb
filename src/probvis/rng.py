"""Counter-based random numbers: every sample is a pure function of (seed, stream, index, dimension).

A shadow segment's `ShadowQuery.key` is such a path key: an estimator draws its own numbers as `uniform(key, dim)`
(or `uniforms(keys, dim)` for an array), so its estimates, too, depend only on the seed.

Renders are therefore identical whatever the thread count or batch size.
"""
import numpy as np
from numba import njit

_GOLD = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_S11 = np.uint64(11)
_INV53 = 1.0 / 9007199254740992.0


@njit(cache=True, error_model="numpy", inline="always")
def mix64(z):
    """SplitMix64 finaliser: a bijective avalanche of a 64-bit word."""
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@njit(cache=True, error_model="numpy", inline="always")
def make_key(seed, stream, index):
    """Key of one sample path: `seed` and `stream` pick a sequence, `index` the element."""
    k = mix64(np.uint64(seed) * _GOLD + np.uint64(stream))
    return mix64(k + np.uint64(index) * _GOLD)


@njit(cache=True, error_model="numpy", inline="always")
def uniform(key, dim):
    """Uniform double in [0, 1) for dimension `dim` of the path with `key`."""
    return np.float64(mix64(key + (np.uint64(dim) + np.uint64(1)) * _GOLD) >> _S11) * _INV53


@njit(cache=True, error_model="numpy")
def uniforms(keys, dim):
    """`uniform(key, dim)` of every key of an array: for estimators written in NumPy."""
    out = np.empty(keys.shape[0])
    for i in range(keys.shape[0]):
        out[i] = uniform(keys[i], dim)
    return out
