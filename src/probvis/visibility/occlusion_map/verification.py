"""Verification: stochastic correction terms that make the occlusion map's shortcuts unbiased.

Any approximate visibility Ṽ becomes unbiased as Ṽ + B (V - Ṽ) / q with B ~ Bernoulli(q) and V traced exactly
when B = 1 (Russian roulette on the correction; Billen, Lagae and Dutré 2014 use the same idea with geometry
proxies). Applied to the occlusion map's three shortcuts:

- lit pairs (Case I) are integrated analytically; with probability q the pair is also sampled and each of its
  segments returns (V - 1) / q: the analytic unoccluded radiance minus the sampled deficit;
- shadowed pairs (Case II) contribute nothing; with probability q each of their segments returns V / q;
- penumbra segments evaluated against a candidate list (exactly, or stochastically by a decomposition) add,
  with probability q, (V - V_list) / q. A listed blocker really blocks, so V - V_list is non-zero only where
  the list says visible: only those need the trace.

q is fixed (`verify=<q>`) or, with `verify=auto`, chosen per pair from what the map knows. A lit or shadowed
pair that k photons agreed with: the rule of succession puts the chance that the next photon disagrees at
1 / (k + 2), and q = clip(2 / (k + 2), Q_MIN, 1). A penumbra pair's list: the Good-Turing estimate of the
blockers it has not seen, the share of recorded blockers recorded only once, and q = clip(that, Q_MIN, 1) -
lists of big, often-recorded blockers (a city's boxes) are rarely verified, lists of many small, once-seen
ones (leaves, a finely tessellated mesh) almost always. Once the verified segments of earlier batches have
measured how often a case's shortcut is wrong (a rate r), no pair of that case is verified less often than
2 sqrt(r): the q that minimises (variance x cost) when the shortcut's own variance is that of binary visibility
(1/4) and it costs about what a trace costs. q of a batch depends only on earlier batches, so the correction
stays unbiased.
"""
import numpy as np
from numba import njit

from ...cases import CASE_LIT, CASE_PENUMBRA, CASE_SHADOWED, CASE_VERIFIED
from ...rng import mix64, uniform
from ...settings import parse_float

Q_MIN = 0.05  # auto: never verify less often than this
Q_LOWEST = 0.001  # a fixed q: the least a user may ask for (as --q of the proxies and caches)
MIN_MEASURED = 64  # verified segments of a case before its measured mismatch rate raises q
SEGMENT_DIM = 1 << 20  # rng dimension of a segment's verification draw, above any estimator's own
_PAIR_SALT = np.uint64(0x5645524946590000)  # derives a camera sample's verification key from its rng key


def probability_problem(value, words):
    """The error message for a setting that is one of `words` or a fixed probability from Q_LOWEST to 1, or None:
    `verify` here, the proxies' `q`."""
    if isinstance(value, str) and value in words:
        return None
    try:
        q = parse_float(value) if isinstance(value, str) else float(value)
    except (TypeError, ValueError):
        q = None
    if isinstance(value, bool) or q is None or not Q_LOWEST <= q <= 1.0:  # NaN fails too
        why = (" (below, each correction weighs more than a thousand segments: the image is the uncorrected one in "
               "practice)") if q is not None and 0.0 <= q < Q_LOWEST else ""
        return f"must be {', '.join(words)} or a probability from {Q_LOWEST:g} to 1, got {value!r}{why}"
    return None


def parse_verify(value):
    """'auto', 'off' or a probability from Q_LOWEST to 1: the error message for anything else, or None."""
    return probability_problem(value, ("auto", "off"))


def auto_q(case, photons, unseen, floors=None):
    """Verification probability per pair from its case, its agreeing (light, shadow) photon counts (..., 2), its
    list's unseen-blocker estimate and the per-case `floors` (`Tally.floors`) measured so far."""
    agreeing = np.where(case == CASE_LIT, photons[..., 0], photons[..., 1])
    q = np.where(case == CASE_PENUMBRA, unseen, 2.0 / (agreeing + 2.0))
    for c, floor in (floors or {}).items():
        q = np.where(case == c, np.maximum(q, floor), q)
    return np.clip(q, Q_MIN, 1.0)


@njit(cache=True, error_model="numpy")
def pair_uniforms(keys, n_emitters):
    """(m, n_emitters) uniforms per camera sample (rng key) and emitter, apart from every other draw of it."""
    out = np.empty((keys.shape[0], n_emitters))
    for i in range(keys.shape[0]):
        k = mix64(keys[i] ^ _PAIR_SALT)
        for e in range(n_emitters):
            out[i, e] = uniform(k, e)
    return out


def flag_verified(case, q, keys):
    """Flag lit and shadowed pairs CASE_VERIFIED with probability q (per pair); returns the flagged cases."""
    draw = pair_uniforms(keys, case.shape[1])
    pick = ((case == CASE_LIT) | (case == CASE_SHADOWED)) & (draw < q)
    return np.where(pick, case | CASE_VERIFIED, case).astype(np.int8)


class Tally:
    """Per case: segments verified and the mismatch V - Ṽ they measured (count, sum, sum of squares)."""

    NAMES = {CASE_LIT: "lit", CASE_SHADOWED: "shadowed", CASE_PENUMBRA: "penumbra"}

    def __init__(self):
        self.pairs = {name: [0, 0] for name in ("lit", "shadowed")}  # pairs, verified pairs
        self.segments = {name: [0, 0] for name in self.NAMES.values()}  # segments of the case, verified ones
        self.mismatch = {name: np.zeros(3) for name in self.NAMES.values()}
        self.q_sum = {name: 0.0 for name in self.NAMES.values()}

    def add_pairs(self, case, flagged):
        for c in (CASE_LIT, CASE_SHADOWED):
            name = self.NAMES[c]
            self.pairs[name][0] += int((case == c).sum())
            self.pairs[name][1] += int((flagged == (c | CASE_VERIFIED)).sum())

    def add_segments(self, c, n_total, mismatch, q, n_unmeasured=0, q_unmeasured=0.0):
        """Case c's `n_total` segments, of which those verified measured `mismatch` with probabilities `q`;
        `n_unmeasured` more were verified with q = 1 (summing to `q_unmeasured`) by a trace alone, their value
        V itself, so their shortcut's value and their mismatch are not known."""
        self.add_sums(c, n_total, len(mismatch) + n_unmeasured, np.sum(mismatch), np.sum(mismatch * mismatch),
                      np.sum(q) + q_unmeasured, len(mismatch))

    def add_sums(self, c, n_total, n_verified, mismatch, mismatch2, q, n_measured=None):
        """As `add_segments`, from sums: the mismatch's and its square's over the `n_measured` verified segments
        that measured it (all `n_verified` unless said), and q's over all verified ones."""
        name = self.NAMES[c]
        self.segments[name][0] += int(n_total)
        self.segments[name][1] += int(n_verified)
        self.mismatch[name] += (int(n_verified if n_measured is None else n_measured), float(mismatch),
                                float(mismatch2))
        self.q_sum[name] += float(q)

    def floors(self):
        """Per case, 2 sqrt(measured mismatch rate) once enough segments were verified (see the module)."""
        out = {}
        for c, name in self.NAMES.items():
            n, _, s2 = self.mismatch[name]
            if n >= MIN_MEASURED:
                out[c] = 2.0 * np.sqrt(s2 / n)
        return out

    def stats(self, setting):
        out = {"setting": setting, "biased": setting == "off"}
        for name in self.NAMES.values():
            n, s, s2 = self.mismatch[name]
            mean = s / n if n else None
            n_ver = self.segments[name][1]
            entry = {"segments": self.segments[name][0], "verified_segments": n_ver,
                     "verified_segment_share": n_ver / max(1, self.segments[name][0]),
                     "mean_q": self.q_sum[name] / n_ver if n_ver else None, "measured_segments": int(n),
                     "mismatch_mean": mean, "mismatch_variance": s2 / n - mean * mean if n else None}
            if name in self.pairs:
                entry["pairs"], entry["verified_pairs"] = self.pairs[name]
                entry["verified_pair_share"] = self.pairs[name][1] / max(1, self.pairs[name][0])
            out[name] = entry
        return out
