"""NEE++ (Guo, Eisemann and Eisemann, "Next Event Estimation++: Visibility Mapping for Efficient Light Transport
Simulation", Pacific Graphics 2020): Russian roulette on shadow rays steered by a voxel-to-voxel visibility
cache. A segment is traced with probability p, its voxel pair's cached unoccluded share clamped to
[min_probability, 1] (1 where the pilot saw none), and weighted 1/p; an untraced one is 0. E = p · V / p = V:
unbiased whatever the cache holds. It skips the segments the cache expects to be blocked: rays saved in
shadow, variance only where the cache is wrong."""
from .base import Option
from .cache import CACHE_OPTIONS, CachedVisibility
from .cache_kernel import RULE_SHARE, CachePlan


class NEEPlusPlusVisibility(CachedVisibility):
    name = "nee++"
    summary = ("NEE++: each segment traced with the probability a voxel-pair visibility cache gives, weighted 1/p "
               "(unbiased)")
    options = CACHE_OPTIONS + (
        Option("min_probability", float, 0.1, "the smallest probability of tracing a segment (bounds its weight 1/p)",
               minimum=0.001, maximum=1.0),
    )

    def plan(self):
        """c = 0; p = the cached share, at least min_probability."""
        return CachePlan(control=0.0, rule=RULE_SHARE, fixed=0.0, min_p=self.params.min_probability)
