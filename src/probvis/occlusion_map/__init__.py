"""Occlusion map (Jensen and Christensen 1995; Billen et al. 2013): light and shadow photons that classify
shading points as lit, shadowed or penumbra, and list the triangles that can block the light in the penumbra."""
from .adaptive import refine
from .lookup import classify_points
from .map import Lookup, OcclusionMap
from .photons import MAX_HITS, Photons, shoot_photons
from .volumetric import closed_orientation, components, blocker_groups

__all__ = ["Lookup", "MAX_HITS", "OcclusionMap", "Photons", "classify_points", "closed_orientation", "components", "refine",
           "blocker_groups",
           "shoot_photons"]
