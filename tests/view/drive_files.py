"""A drive for the tests of `acq view`'s drive layers: the 2 s simulated drive of
tests/conftest.py (``short_drive``) copied into a folder with its calib.yaml, coloured
beside it by `acq colorize`'s core with each point's frame and pixel kept (the truth the
frame tool's answers are checked against)."""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from acq.camera import calibfile
from acq.cloud import colorize
from acq.cloud.chunks import ChunkResult
from acq.sim.drive_log import DriveTruth


@dataclass(frozen=True)
class ColouredDrive:
    """The folder, its log, calib.yaml and cloud (``cloud``, a PLY, or None), and per
    point of the cloud, in file order: its camera index, frame and pixel as colouring
    found them (NaN none)."""

    folder: Path
    log: Path
    calib: Path
    cloud: Path | None
    camera: np.ndarray
    frame: np.ndarray
    uv: np.ndarray
    truth: DriveTruth


def coloured_drive(
    short_drive: tuple[DriveTruth, Path], folder: Path, cloud_name: str | None = "cloud.ply"
) -> ColouredDrive:
    """``short_drive`` copied into ``folder`` (made) and coloured there as ``cloud_name``
    (None: left uncoloured, no cloud beside the log)."""
    truth, calib = short_drive
    folder.mkdir(parents=True, exist_ok=True)
    log = Path(shutil.copy2(truth.files[0], folder))
    calib = Path(shutil.copy2(calib, folder / "calib.yaml"))
    if cloud_name is None:
        empty = np.zeros(0)
        return ColouredDrive(folder, log, calib, None, empty, empty, np.zeros((0, 2)), truth)
    results: list[ChunkResult] = []
    cloud = folder / cloud_name
    colorize.run([log], calibfile.load(calib), cloud, results=results, want_uv=True)
    uv = np.concatenate([r.uv for r in results if r.uv is not None])
    camera = np.concatenate([r.camera for r in results])
    frame = np.concatenate([r.frame for r in results])
    return ColouredDrive(folder, log, calib, cloud, camera, frame, uv, truth)
