"""Walker's alias tables: a discrete distribution sampled in O(1) with one uniform number and no branch on it
(emitter triangles by area, environment cells by luminance)."""
import numpy as np
from numba import njit


@njit(cache=True, error_model="numpy")
def alias_table(weights):
    """Walker's alias table of non-negative `weights` (Vose's construction): column k = floor(u n) is kept
    with probability prob[k], else alias[k] is taken, so index i comes out with probability w_i / sum(w)."""
    n = weights.shape[0]
    prob = np.ones(n)
    alias = np.arange(n)
    total = weights.sum()
    if total <= 0.0:
        return prob, alias
    scaled = weights * (n / total)
    small = np.empty(n, np.int64)
    large = np.empty(n, np.int64)
    ns = nl = 0
    for i in range(n):
        if scaled[i] < 1.0:
            small[ns] = i
            ns += 1
        else:
            large[nl] = i
            nl += 1
    while ns > 0 and nl > 0:
        ns -= 1
        s = small[ns]
        g = large[nl - 1]
        prob[s] = scaled[s]
        alias[s] = g
        scaled[g] -= 1.0 - scaled[s]
        if scaled[g] < 1.0:  # g now falls short itself: it joins the small ones, to be topped up
            nl -= 1
            small[ns] = g
            ns += 1
    return prob, alias


@njit(cache=True, error_model="numpy", inline="always")
def alias_sample(prob, alias, lo, n, u):
    """Index (within lo..lo+n-1, relative to lo) drawn by the alias table of that range with uniform u."""
    x = u * n
    k = min(np.int64(x), n - 1)
    other = alias[lo + k]  # loaded unconditionally: an array read inside the select costs Numba a refcount
    return k if x - k < prob[lo + k] else other
