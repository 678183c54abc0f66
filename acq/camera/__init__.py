"""Cameras: the models (equidistant, Kannala-Brandt, pinhole), calib.yaml that describes a
rig's cameras and their poses, and the projection core.

``from acq import camera_models`` (the name ARCHITECTURE.md's API uses) gives this package.
"""

from __future__ import annotations

from pathlib import Path

from acq.camera import calibfile
from acq.camera.camera_models import CameraModel, Equidistant, KannalaBrandt, Pinhole, from_dict

__all__ = ["CameraModel", "Equidistant", "KannalaBrandt", "Pinhole", "from_dict", "load"]


def load(path: str | Path, camera: str | None = None) -> CameraModel:
    """The camera model of ``camera`` (or of the only camera) in a calib.yaml."""
    return calibfile.load(path, intrinsics_only=True).camera(camera).model
