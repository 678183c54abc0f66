"""`acq view`: a local web page that draws clouds, meshes and drives with three.js, served
with its libraries from the package (no network): :class:`ViewServer` serves the layers
(:class:`Layer`, checked by :func:`layers_of`; a drive's by :mod:`acq.view.drive`, the
frame a point was coloured from by :mod:`acq.view.frames`)."""

from acq.view.layers import Layer, layers_of
from acq.view.server import AddressError, ViewServer

__all__ = ["AddressError", "Layer", "ViewServer", "layers_of"]
