"""Coloured clouds: a drive read into arrays, points placed at their own time and
coloured from the camera frames (the pipeline of ``acq colorize``), written as PLY or
LAS, with a preview image."""

from acq.cloud.drive_log import DriveLog, camera_calib, read_log
from acq.cloud.ply import PLY_DTYPE, PlyStream
from acq.cloud.points import Cloud
from acq.cloud.preview import UNCOLOURED_RGB, preview_image, preview_png

__all__ = [
    "PLY_DTYPE",
    "UNCOLOURED_RGB",
    "Cloud",
    "DriveLog",
    "PlyStream",
    "camera_calib",
    "preview_image",
    "preview_png",
    "read_log",
]
