"""Occlusion map (Jensen and Christensen 1995; Billen et al. 2013): light and shadow photons that classify
shading points as lit, shadowed or penumbra, and list the triangles that can block the light in the penumbra.

Modules: `photons` (the photon pass), `map` (kd-trees and look-ups), `lookup` (classification kernels),
`adaptive_photons` (extra photons aimed at uncertain regions), `components` (connected and closed components
of the meshes, for candidate groups and volumetric culling), `estimator` (the `occlusion-map` estimator).
"""
from .adaptive_photons import refine
from .components import blocker_groups, closed_orientation, components
from .estimator import OcclusionMapVisibility
from .lookup import classify_points
from .map import Lookup, OcclusionMap
from .photons import MAX_HITS, Photons, shoot_photons

__all__ = ["Lookup", "MAX_HITS", "OcclusionMap", "OcclusionMapVisibility", "Photons", "blocker_groups",
           "classify_points", "closed_orientation", "components", "refine", "shoot_photons"]
