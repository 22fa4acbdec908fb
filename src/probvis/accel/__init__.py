"""Acceleration: a SAH BVH over the scene's triangles and counted ray queries against it."""
from .bvh import BVH, build_bvh
from .traversal import any_hit, closest_hit

__all__ = ["BVH", "any_hit", "build_bvh", "closest_hit"]
