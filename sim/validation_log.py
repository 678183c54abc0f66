"""A simulated validation recording (MCAP) of the paper's §4.2 pattern in the synthetic
street, with the truth.

The pattern (:func:`acq.sim.world.validation_pattern`) stands on the left sidewalk of a
street (``Street.generate(seed, pattern_at=at_m)``, that stretch cleared of parked cars,
poles and buildings): six red/green horizontal bars at |y| = 5 m (0.8-3.3 m above the
road), a raised panel of blue/yellow squares behind them at |y| = 6 m (0.5-4.1 m). The
vehicle is parked at the left kerb (y = ``park_y`` = 3.2 m, facing +x, the camera looking
left) with its scan plane x = ``at_m`` through the middle of the pattern: the bars 1.8 m
from the scanner, the panel 2.8 m, the laser line crossing every bar and, through the
gaps, the panel (through square centres). It stands still for ``duration_s`` s.

Rendering with the street's ray caster (:mod:`acq.sim.raycast`), in colour: every pixel
cast through the TRUE lens from the TRUE camera pose (2x2 supersampled), blurred (sigma
``blur_px``), RGB noise, JPEG; every scan cast by :func:`acq.sim.sensors.render_scan` with the
rig's 10 mm range noise. Topics and metadata as :func:`acq.sim.board_log.write_board_log`
writes them (the stored calibration holds the true intrinsics and the TRUE
camera_to_laser). The truth per beam (:data:`LABELS`) is what the caster hit: its
material and colour. World frame and units as in :mod:`acq.sim.world`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from acq.calib.validate import DEFAULT_COLOURS
from acq.camera.calibfile import Calibration, CameraCalib
from acq.geometry.transforms import Rigid
from acq.log import schemas
from acq.records import Frame
from acq.sim.board_log import SIM_TIME_BASE, open_sim_log, pixel_rays, scan_events, write_events
from acq.sim.raycast import NO_RAY, cast
from acq.sim.sensors import camera_to_world, render_scan
from acq.sim.world import Material, Rig, Street, Trajectory, default_rig

__all__ = [
    "LABELS",
    "PARK_Y",
    "PATTERN_AT",
    "ValidationLog",
    "labels",
    "parked",
    "render",
    "write_validation_log",
]

LABELS = ("none", "red", "green", "blue", "yellow", "ground", "sky", "other")
"""What a beam hit (index = label): nothing cast, a pattern colour, the road or sidewalk,
nothing (sky), anything else (facades, cars, poles, ...)."""

PATTERN_AT = 20.0  # m, street x of the pattern (and of the parked vehicle's scan plane)
PARK_Y = 3.2  # m, the parked vehicle's y: at the left kerb as the parked cars stand


def labels(material: np.ndarray, colour: np.ndarray) -> np.ndarray:
    """(N,) :data:`LABELS` index of ray-caster hits: ``material`` (N,) ``Material`` ids and
    ``colour`` (N,3) BGR; a pattern colour only on the pattern's materials (SOLID bars,
    CHECKER panel)."""
    out = np.full(material.shape, LABELS.index("other"), np.int64)
    out[material == NO_RAY] = LABELS.index("none")
    out[material == Material.SKY] = LABELS.index("sky")
    out[(material == Material.ROAD) | (material == Material.SIDEWALK)] = LABELS.index("ground")
    pattern = (material == Material.SOLID) | (material == Material.CHECKER)
    for name, rgb in DEFAULT_COLOURS.items():
        out[pattern & np.all(colour == rgb[::-1], axis=1)] = LABELS.index(name)
    return out


@dataclass(frozen=True)
class ValidationLog:
    """What :func:`write_validation_log` wrote: the file(s), the true ``camera_to_laser``,
    the ``calibration`` stored in the log (true intrinsics and extrinsic), the ``street``
    and the parked ``vehicle`` (a still trajectory), and per beam the truth:
    ``beam_label`` (n_steps,) :data:`LABELS` index of what each beam hit and
    ``beam_range`` (n_steps,) its noiseless range (m, inf for none)."""

    files: list[Path]
    truth: Rigid
    calibration: Calibration
    street: Street
    vehicle: Trajectory
    beam_label: np.ndarray
    beam_range: np.ndarray
    start_ns: int

    def beam_colour(self) -> list[str]:
        """The :data:`LABELS` name of each beam's hit."""
        return [LABELS[i] for i in self.beam_label]


def parked(at_m: float = PATTERN_AT, park_y: float = PARK_Y, rig: Rig | None = None) -> Trajectory:
    """The still vehicle at y = ``park_y`` m, facing +x, its scan plane at x = ``at_m`` m."""
    rig = rig or default_rig()
    return Trajectory(speed=0.0, x0=at_m - float(rig.laser_to_vehicle.translation[0]), y0=park_y)


def render(street: Street, vehicle: Trajectory, rig: Rig, supersample: int = 2) -> np.ndarray:
    """(H,W,3) float32 BGR image of the street at time 0 through the TRUE lens from the
    TRUE camera pose, ``supersample`` x ``supersample`` rays per pixel averaged; black
    outside the lens's field of view."""
    lens, k = rig.lens, supersample
    rays, valid = pixel_rays(lens, k)
    pose = camera_to_world(vehicle, rig, 0.0)
    idx = np.flatnonzero(valid)
    hit = cast(street, pose.translation, rays[idx], pose.rotation, idx, len(rays))
    img = hit.colour.astype(np.float32).reshape(lens.height * k, lens.width * k, 3)
    if k > 1:
        img = img.reshape(lens.height, k, lens.width, k, 3).mean(axis=(1, 3))
    return img


def write_validation_log(
    directory: Path,
    seed: int = 0,
    *,
    duration_s: float = 2.0,
    rig: Rig | None = None,
    street: Street | None = None,
    at_m: float = PATTERN_AT,
    park_y: float = PARK_Y,
    blur_px: float = 0.6,
    pixel_noise: float = 2.0,
    jpeg_quality: int = 92,
    start_ns: int = 1_000_000_000_000,
) -> ValidationLog:
    """Write the recording (see the module docstring) into ``directory``; the truth.

    ``street``: the scene (default ``Street.generate(seed, 80 m, pattern_at=at_m)``); the
    vehicle parks at y = ``park_y`` m with its scan plane at x = ``at_m`` m."""
    rig = rig or default_rig()
    street = street if street is not None else Street.generate(seed, 80.0, pattern_at=at_m)
    vehicle = parked(at_m, park_y, rig)
    rng = np.random.default_rng(seed)
    truth = rig.camera_to_laser
    calib = Calibration(cameras={"camera": CameraCalib(rig.lens, truth)})
    writer = open_sim_log(directory, "validation", rig, calib)

    img = np.asarray(cv2.GaussianBlur(render(street, vehicle, rig), (0, 0), blur_px), np.float32)
    noise = [rng.normal(0.0, pixel_noise, img.shape).astype(np.float32) for _ in range(4)]
    lens = rig.lens
    events: list[tuple[int, str, bytes]] = []
    for k in range(int(duration_s * rig.fps) + 1):
        stamp = start_ns + round(k / rig.fps * 1e9)
        bgr = np.clip(np.rint(img + noise[k % len(noise)]), 0, 255).astype(np.uint8)
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
        if not ok:
            raise RuntimeError("JPEG encoding failed")
        frame = Frame(stamp + 2_000_000, stamp, k, lens.width, lens.height, jpeg=buf.tobytes())
        events.append(
            (
                stamp,
                "/camera/image/compressed",
                schemas.compressed_image(frame, "camera", SIM_TIME_BASE.to_log(stamp)),
            )
        )
    scans = [
        render_scan(street, vehicle, rig, k * rig.scan_period, rng)
        for k in range(int(duration_s / rig.scan_period) + 1)
    ]
    for k, scan in enumerate(scans):
        events += scan_events(rig, scan.ranges, k, start_ns + round(scan.t0 * 1e9))
    write_events(writer, events, start_ns, duration_s)
    label = labels(scans[0].material, scans[0].colours)  # the vehicle stands still
    return ValidationLog(
        writer.files, truth, calib, street, vehicle, label, scans[0].true_ranges, start_ns
    )
