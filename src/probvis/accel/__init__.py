"""Acceleration: a SAH BVH over the scene's triangles and counted ray queries against it.

Public interface: `build_bvh` and `BVH`/`BVHArrays`; packet queries for the renderer (`nearest_hits`,
`occluded_segments`, and `occluded_packet` for kernels that trace their own packets); `all_hits` for photons;
the candidate-list test (`first_blocker`, `visibility_from_lists`, `culled`); the watertight triangle test
(`ray_setup`, `hit_triangle`). `closest_hit` and `any_hit` trace one ray at a time: test oracles.
"""
from .bvh import BVH, BVHArrays, build_bvh
from .candidates import CandidateGeometry, buffered_blocker, culled, first_blocker, visibility_from_lists
from .packet import (MAX_PACKET, SHADOW_PACKET, any_hit_packets, closest_hit_packets, nearest_hits, occluded_packet,
                     occluded_segments, packet_starts, packet_work, root_record)
from .traversal import CHUNK, all_hits, any_hit, closest_hit, hit_triangle, ray_setup

__all__ = ["BVH", "BVHArrays", "CHUNK", "CandidateGeometry", "MAX_PACKET", "SHADOW_PACKET", "all_hits", "any_hit", "any_hit_packets", "buffered_blocker", "build_bvh",
           "closest_hit", "closest_hit_packets", "culled", "first_blocker", "hit_triangle", "nearest_hits",
           "occluded_packet", "occluded_segments", "packet_starts", "packet_work", "ray_setup", "root_record",
           "visibility_from_lists"]
