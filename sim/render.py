"""`acq sim render`: one instant of the simulated rig, coloured by the projection core.

Renders the fisheye frame at time t, simulates the laser scan around t, brings every
laser point into the laser frame at the frame's time (each point was measured at its
own time, and the vehicle moves 5.6 m/s), colours it with ``acq.camera.projection`` and the
rig's true calibration, and compares with the simulator's truth: the true pixel of the
noise-free point and the true colour of the surface the laser hit.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from acq.atomic_write import write_text
from acq.calib.plots import draw_legend
from acq.camera import calibfile, projection
from acq.camera.calibfile import Calibration, CameraCalib
from acq.errors import InputValueError
from acq.geometry.transforms import Rigid
from acq.provenance import SOFTWARE, write_image
from acq.sim import sensors, world

__all__ = ["CAMERAS", "OverlayResult", "check_camera", "render_overlay", "write"]

CAMERAS = ("camera", "left", "right", "rear")  # the one-camera rig's, the three-camera rig's

_MAGENTA = (255, 0, 255)


@dataclass(frozen=True)
class OverlayStats:
    """How the projection core's result compares with the simulator's truth."""

    time_s: float
    laser_points: int  # steps with an echo
    in_image: int  # of those, projected onto the sensor
    occluded: int  # of those, hidden from the camera by something nearer
    pixel_error_rms_px: float  # core pixel of the measured point vs true pixel of the true one
    pixel_error_max_px: float
    colour_agreement: float  # share of visible points whose colour equals the truth's


@dataclass(frozen=True)
class OverlayResult:
    image: np.ndarray  # (H,W,3) uint8 BGR, the rendered frame
    overlay: np.ndarray  # the picture written to overlay.png
    calibration: Calibration  # the rig's true calibration
    uv: np.ndarray  # (N,2) float32 px of the laser points with an echo
    visible: np.ndarray  # (N,) bool: on the sensor and not occluded
    colours: np.ndarray  # (N,3) uint8 from the projection core
    stats: OverlayStats


def check_camera(name: str) -> None:
    """InputValueError naming the simulated cameras unless ``name`` is one."""
    if name not in CAMERAS:
        raise InputValueError(
            f"--camera {name}: the simulated rig has no such camera (has {', '.join(CAMERAS)})"
        )


def render_overlay(
    time_s: float = 2.0,
    seed: int = 0,
    exact_equidistant: bool = False,
    range_noise: float | None = None,
    camera: str = "camera",
) -> OverlayResult:
    """The frame at ``time_s`` and the scan that contains that instant, compared with truth.

    ``range_noise`` (m) overrides the simulated scanner's noise (0 for exact ranges).
    ``camera``: one of :data:`CAMERAS` (``camera``, the one-camera rig's; ``left``,
    ``right``, ``rear``: that camera of the three-camera rig, its exposure and white
    balance held constant); InputValueError listing them for another name.
    """
    check_camera(camera)
    street = world.Street.generate(seed=seed)
    traj = world.Trajectory()
    rig = world.default_rig(exact_equidistant, cameras=1 if camera == "camera" else 3)
    rig = rig.only(camera).with_camera(camera, photometry=world.Photometry())
    if range_noise is not None:
        rig = replace(rig, range_noise=range_noise)
    calib = Calibration(
        laser="laser",
        cameras={camera: CameraCalib(rig.lens, rig.camera_to_laser, method="simulator truth")},
        laser_to_vehicle=rig.laser_to_vehicle,
    )
    frame = sensors.render_frame_truth(street, traj, rig, time_s)
    t0 = time_s - rig.scan_period / 2
    scan = sensors.render_scan(street, traj, rig, t0, np.random.default_rng(seed))

    echo = np.isfinite(scan.ranges)
    r = scan.ranges[echo].astype(np.float64)
    a = scan.angles[echo]
    P_own = np.stack([r * np.cos(a), r * np.sin(a), np.zeros_like(r)], axis=1)
    # Each point from the laser frame at its own time into the laser frame at frame time.
    R_own, o_own = sensors.laser_to_world(traj, rig, scan.times[echo])
    world_pts = np.einsum("nij,nj->ni", R_own, P_own) + o_own
    R_now, o_now = sensors.laser_to_world(traj, rig, np.array([time_s]))
    P_laser = Rigid(R_now[0], o_now[0]).inverse().apply(world_pts)

    cam = calib.camera(camera)
    colours, valid = projection.colorize(P_laser, cam.model, cam.camera_to_laser, frame.image)
    uv, _ = projection.project(P_laser, cam.model, cam.camera_to_laser)

    # Occlusion from the rendered depth at each point's pixel.
    cam_to_world = sensors.camera_to_world(traj, rig, time_s)
    dist = np.linalg.norm(world_pts - cam_to_world.translation, axis=1)
    iu = np.clip(np.rint(uv[:, 0]), 0, rig.lens.width - 1).astype(int)
    iv = np.clip(np.rint(uv[:, 1]), 0, rig.lens.height - 1).astype(int)
    depth = frame.depth[iv, iu]
    occluded = valid & (depth < dist - 0.05 - 0.02 * dist)
    visible = valid & ~occluded

    true_uv, true_valid = sensors.true_pixels(scan.points[echo], traj, rig, time_s)
    both = visible & true_valid
    err = np.linalg.norm(uv[both] - true_uv[both], axis=1)
    agree = np.all(colours[visible] == scan.colours[echo][visible], axis=1)
    stats = OverlayStats(
        time_s=time_s,
        laser_points=int(echo.sum()),
        in_image=int(valid.sum()),
        occluded=int(occluded.sum()),
        pixel_error_rms_px=float(np.sqrt(np.mean(err**2))) if err.size else float("nan"),
        pixel_error_max_px=float(err.max()) if err.size else float("nan"),
        colour_agreement=float(agree.mean()) if agree.size else float("nan"),
    )
    overlay = draw_overlay(frame.image, uv[visible], colours[visible])
    return OverlayResult(frame.image, overlay, calib, uv, visible, colours, stats)


def draw_overlay(
    image: np.ndarray, uv: np.ndarray, colours: np.ndarray, zoom: int = 3
) -> np.ndarray:
    """The frame with the laser profile on it, beside a zoom on the profile.

    Left: the frame, the profile between two thin magenta guides 4 px to either side,
    each point a 3x3 square of the colour the projection core gave it. Where the
    calibration and timing are right the squares melt into the picture. Right: a
    ``zoom``-times enlargement of the stretch with the most colour changes, each point a
    square of its colour in a black frame: the colours must change exactly where the
    facade, kerb and road edges cross the profile.
    """
    out = image.copy()
    h, w = image.shape[:2]
    pts = np.rint(uv).astype(int)
    for dx in (-4, 4):
        guide = (pts + np.array([dx, 0])).reshape(-1, 1, 2).astype(np.int32)
        cv2.polylines(out, [guide], False, _MAGENTA, 1, cv2.LINE_AA)
    for (u, v), c in zip(pts, colours, strict=True):
        out[max(v - 1, 0) : v + 2, max(u - 1, 0) : u + 2] = c
    if pts.size == 0:
        return out
    # The window: centred on the profile where its colours change most (edges).
    changes = np.flatnonzero(np.any(np.diff(colours.astype(int), axis=0) != 0, axis=1))
    centre = np.median(pts[changes] if changes.size else pts, axis=0).astype(int)
    side = h // zoom
    x0 = int(np.clip(centre[0] - side // 2, 0, w - side))
    y0 = int(np.clip(centre[1] - side // 2, 0, h - side))
    big = cv2.resize(
        image[y0 : y0 + side, x0 : x0 + side], (side * zoom, side * zoom),
        interpolation=cv2.INTER_NEAREST,
    )  # fmt: skip
    zuv = np.rint((uv - [x0, y0]) * zoom + (zoom - 1) / 2).astype(int)
    inside = (zuv >= 0).all(axis=1) & (zuv < side * zoom).all(axis=1)
    r = zoom
    for u, v in zuv[inside]:
        big[max(v - r - 1, 0) : v + r + 2, max(u - r - 1, 0) : u + r + 2] = 0
    for (u, v), c in zip(zuv[inside], colours[inside], strict=True):
        big[max(v - r, 0) : v + r + 1, max(u - r, 0) : u + r + 1] = c
    cv2.rectangle(out, (x0, y0), (x0 + side, y0 + side), _MAGENTA, 1)
    draw_legend(out, [
        (None, "laser points of one scan, each in the colour the projection gave it"),
        (_MAGENTA, "guides 4 px either side of the profile; the box zoomed at right"),
    ])  # fmt: skip
    panel = np.zeros((h, side * zoom, 3), np.uint8)
    panel[: side * zoom] = big
    draw_legend(panel, [(None, f"x{zoom}: each point a square of its colour, black rim")])
    return np.hstack([out, panel])


def write(
    out: str | Path, time_s: float, seed: int, exact_equidistant: bool, camera: str = "camera"
) -> OverlayStats:
    """Write frame.png, overlay.png, calib.yaml and summary.json to ``out``; the stats."""
    result = render_overlay(time_s, seed, exact_equidistant, camera=camera)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for name, image in (("frame.png", result.image), ("overlay.png", result.overlay)):
        write_image(out / name, image)
    calibfile.save(result.calibration, out / "calib.yaml")
    summary = {"software": SOFTWARE} | asdict(result.stats)  # the mark first (provenance)
    write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    return result.stats
