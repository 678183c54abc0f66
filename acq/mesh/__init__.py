"""Facets of the laser's scan grid (:mod:`acq.mesh.organized`)."""

from acq.mesh.organized import FacetRules, grid_facets

__all__ = ["FacetRules", "grid_facets"]
