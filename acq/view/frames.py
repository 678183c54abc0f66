"""The frame a cloud's point was coloured from (the paper's §4 check by eye): the point's
row read from the cloud (PLY ``scalar_camera``/``scalar_frame`` and ``camera <k> <name>``
comments; LAS/LAZ ``camera``/``frame`` extra bytes and the VLR acq 1), its pixel in that
frame (its world position projected with the frame's pose and the camera's model, the
kernel the colouring used), and the frame's JPEG as recorded in the log.

Times host monotonic ns unless ``_s``; metres; pixels from the image's top-left corner."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from acq.camera import projection
from acq.errors import InputError, first_line
from acq.geometry.transforms import Rigid
from acq.log.drive_log import read_log
from acq.time.utc import utc_seconds
from acq.view.cloud_rows import NO_CAMERA, rows_of
from acq.view.drive import Drive
from acq.view.errors import FrameError

__all__ = ["NO_CAMERA", "FrameError", "PointRow", "frame_jpeg", "point_frame", "point_row"]

_FRAME_WINDOW_NS = (2 * 10**9, 5 * 10**9)  # log time read before/after a frame's stamp


@dataclass(frozen=True)
class PointRow:
    """A cloud's point: ``xyz`` m, its source ``camera`` (name, None: none), ``frame``
    (index among that camera's frames in the session, -1 none), the cloud's ``frame``
    of reference ("world" or "laser")."""

    row: int
    xyz: tuple[float, float, float]
    camera: str | None
    frame: int
    world: bool


def point_row(path: Path, row: int) -> PointRow:
    """Row ``row`` of the cloud ``path`` (PLY as `acq colorize` writes it, LAS/LAZ/COPC);
    FrameError for a row outside the file or a cloud without source cameras."""
    rows = rows_of(path)
    try:
        if not 0 <= row < rows.count:
            raise FrameError(f"{path.name}: no point {row} (it has {rows.count})")
        if not {"camera", "frame"} <= rows.columns:
            raise FrameError(f"{path.name}: its points do not say which camera coloured them", 409)
        point = next(rows.read(row, row + 1))
    finally:
        rows.close()
    x, y, z = (float(v) for v in point["xyz"][0])
    camera, frame = int(point["camera"][0]), int(point["frame"][0])
    if camera == NO_CAMERA or frame < 0:
        return PointRow(row, (x, y, z), None, -1, rows.world)
    if camera >= len(rows.cameras):
        raise FrameError(
            f"{path.name}: point {row}'s camera {camera} is not named in the file", 409
        )
    return PointRow(row, (x, y, z), rows.cameras[camera], frame, rows.world)


def point_frame(drive: Drive, point: PointRow) -> dict[str, Any]:
    """What ``/api/frame`` answers for ``point`` of a cloud made from ``drive``: the
    camera, the frame (session index), its time (UTC s, and s since the drive's first
    scan), the point's pixel in it and whether it falls inside the image; ``camera``
    None for a point no camera coloured. FrameError when the cloud names a camera or
    frame the drive does not have."""
    out: dict[str, Any] = {"row": point.row, "xyz": list(point.xyz), "camera": point.camera}
    if point.camera is None:
        return out | {"message": f"point {point.row} was coloured by no camera"}
    if drive.job is None:
        raise FrameError(f"{drive.name}: no calibration or no frames: no frame to show", 409)
    names = [c.name for c in drive.job.cameras]
    if point.camera not in names:
        raise FrameError(
            f"the cloud's camera {point.camera} is not one of {drive.name}'s calibrated "
            f"cameras ({', '.join(names)})",
            409,
        )
    c = names.index(point.camera)
    cj = drive.job.cameras[c]
    if point.frame >= cj.frame_old.size:
        raise FrameError(
            f"{drive.name}: camera {cj.name} has {cj.frame_old.size} frames, no frame "
            f"{point.frame}: is the cloud made from this log?",
            409,
        )
    t_ns = int(drive.frame_times(c)[point.frame])
    if point.world and drive.trajectory is not None:
        if not drive.trajectory.covers(np.array([t_ns]))[0]:
            raise FrameError(f"{drive.name}: frame {point.frame} is outside the trajectory", 409)
        R, p = drive.frame_poses(c, np.array([point.frame]))
        camera_to_points = Rigid(R[0], p[0])
    else:  # a cloud in the laser frame: the camera where the calibration puts it
        camera_to_points = cj.cam.camera_to_laser
    uv, valid = projection.project(np.array([point.xyz]), cj.cam.model, camera_to_points)
    utc = float(utc_seconds(np.array([t_ns]), drive.clock)[0])
    return out | {
        "frame": point.frame,
        "utc_s": utc,
        "t_s": (t_ns - drive.span_ns[0]) * 1e-9,
        "pixel": [float(uv[0, 0]), float(uv[0, 1])],
        "in_image": bool(valid[0]),
        "size": [cj.cam.model.width, cj.cam.model.height],
    }


def frame_jpeg(drive: Drive, camera: str, frame: int) -> bytes:
    """The JPEG bytes of ``camera``'s frame ``frame`` (session index) as the log holds
    them; FrameError for a camera or frame the drive does not have."""
    if drive.job is None or camera not in [c.name for c in drive.job.cameras]:
        raise FrameError(f"{drive.name}: no calibrated camera {camera}")
    cj = next(c for c in drive.job.cameras if c.name == camera)
    if not 0 <= frame < cj.frame_old.size:
        raise FrameError(
            f"{drive.name}: camera {camera} has no frame {frame} ({cj.frame_old.size})"
        )
    return _jpeg(tuple(drive.files), camera, int(cj.frame_old[frame]))


@functools.lru_cache(maxsize=32)
def _jpeg(files: tuple[Path, ...], camera: str, stamp_ns: int) -> bytes:
    """The JPEG of ``camera`` recorded with ``stamp_ns``: the log read about that time
    (its whole when the frame was not there)."""
    before, after = _FRAME_WINDOW_NS
    for span in ((stamp_ns - before, stamp_ns + after), (None, None)):
        try:
            log = read_log(files, cameras=[camera], start_ns=span[0], end_ns=span[1],
                           jpegs=True, returns=False)  # fmt: skip
        except InputError as e:  # e.g. no scan in the window: the whole log then
            if span[0] is None:
                raise FrameError(f"{files[0].name}: {first_line(e)}", 409) from None
            continue
        frames = log.cameras.get(camera)
        if frames is not None and frames.jpegs:
            hit = np.flatnonzero(frames.frame_ns == stamp_ns)
            if hit.size:
                return frames.jpegs[int(hit[0])]
    raise FrameError(f"{files[0].name}: camera {camera}'s frame stamped {stamp_ns} ns is not in it")
