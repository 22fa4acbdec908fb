"""Acceleration: a SAH BVH over the scene's triangles and counted ray queries against it."""
from .bvh import BVH, build_bvh
from .packet import (MAX_PACKET, any_hit_packets, closest_hit_packets, nearest_hits, occluded_packet, occluded_segments,
                     packet_starts, packet_work, root_record)
from .traversal import all_hits, any_hit, closest_hit

__all__ = ["BVH", "MAX_PACKET", "all_hits", "any_hit", "any_hit_packets", "build_bvh", "closest_hit",
           "closest_hit_packets", "nearest_hits", "occluded_packet", "occluded_segments", "packet_starts", "packet_work",
           "root_record"]
