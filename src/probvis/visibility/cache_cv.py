"""A visibility control variate from a cache (the idea of Clarberg and Akenine-Möller, "Exploiting Visibility
Correlation in Direct Illumination", EGSR 2008, with NEE++'s voxel-pair cache as the approximation). A
segment's estimate is c + B (V − c) / q: c its voxel pair's cached unoccluded share, B a coin of probability q.
E = V whatever c and q. Where the cache is certain (a voxel pair fully lit or fully shadowed) the correction is
rarely traced and c stands in for V; in penumbra it nearly always is."""
from .base import Option
from .cache import CACHE_OPTIONS, CachedVisibility
from .cache_kernel import RULE_UNCERTAINTY, CachePlan


class CacheControlVariateVisibility(CachedVisibility):
    name = "cache-cv"
    summary = "cached voxel-pair visibility c plus the correction (V - c)/q traced with probability q (unbiased)"
    options = CACHE_OPTIONS + (
        Option("q", float, None, "the probability of tracing a correction; default: per segment "
               "min(1, max(min_q, 2 sqrt(c (1 - c)))), 1 where the pilot never saw its voxel pair",
               minimum=0.001, maximum=1.0),
        Option("min_q", float, 0.1, "the smallest automatic q (bounds the correction's weight 1/q)",
               minimum=0.001, maximum=1.0),
    )

    def __init__(self, **options):
        self.refuse_both(options, "q", "min_q")  # min_q bounds the automatic q
        super().__init__(**options)

    def plan(self):
        """c = the cached share; q fixed, or larger where c is uncertain."""
        return CachePlan(control=1.0, rule=RULE_UNCERTAINTY, fixed=self.params.q or 0.0, min_p=self.params.min_q)
