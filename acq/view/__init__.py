"""`acq view`: a local web page that draws clouds and meshes with three.js, served with
its libraries from the package (no network): :class:`ViewServer` serves the layers
(:class:`Layer`, checked by :func:`layers_of`)."""

from acq.view.layers import Layer, layers_of
from acq.view.server import AddressError, ViewServer

__all__ = ["AddressError", "Layer", "ViewServer", "layers_of"]
