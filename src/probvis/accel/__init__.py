"""Acceleration: a SAH BVH over the scene's triangles and counted ray queries against it."""
from .bvh import BVH, build_bvh
from .traversal import all_hits, any_hit, closest_hit

__all__ = ["BVH", "all_hits", "any_hit", "build_bvh", "closest_hit"]
