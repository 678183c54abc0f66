"""Facets of the street: triangles joining the laser's returns where the surface is
continuous (:mod:`acq.mesh.organized`)."""

from acq.mesh.organized import FacetRules, grid_facets

__all__ = ["FacetRules", "grid_facets"]
