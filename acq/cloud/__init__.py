"""Coloured clouds: a drive's points placed at their own time and coloured from the
camera frames (the pipeline of ``acq colorize``), written as PLY or LAS, with a preview
image."""

from acq.cloud.ply import PLY_DTYPE, PlyStream
from acq.cloud.points import Cloud
from acq.cloud.preview import UNCOLOURED_RGB, preview_image, preview_png

__all__ = [
    "PLY_DTYPE",
    "UNCOLOURED_RGB",
    "Cloud",
    "PlyStream",
    "preview_image",
    "preview_png",
]
