"""A simulated validation recording (MCAP) of the paper's §4.2 pattern, with the truth.

The pattern, in front of the still rig on the camera's side (laser y < 0): a front set
of ``n_strips`` horizontal bars ``strip_m`` tall (along laser x, up) and 3 m long (along
laser z, forward), ``gap_m`` apart, alternately red and green, on the plane ``front_m``
m from the scanner; behind it a wall ``back_m`` m away painted with blue and yellow
squares (``square_m``). The scan plane (laser z = 0) is vertical, so the laser line
crosses every bar and, through the gaps, the wall. The ground (grey) is ``ground_m``
below the scanner; the rest is a grey sky.

Rendering as :mod:`sim.board_log` does, in colour: every pixel ray-cast through the TRUE
lens (2x2 supersampled), blurred (sigma ``blur_px``), RGB noise, JPEG; scans through the
TRUE camera_to_laser with the rig's 10 mm range noise. Topics and metadata as
:func:`sim.board_log.write_board_log` writes them (the stored calibration holds the true
intrinsics and the TRUE camera_to_laser). The rig stands still for ``duration_s`` s.

World frame = the laser frame (x = up, y = vehicle right, z = vehicle forward); metres.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from acq import schemas
from acq.calibfile import Calibration, CameraCalib
from acq.records import Frame
from acq.transforms import Rigid
from acq.validate import DEFAULT_COLOURS
from sim.board_log import open_sim_log, pixel_rays, scan_events, write_events
from sim.world import Rig, default_rig

__all__ = ["LABELS", "PatternScene", "ValidationLog", "cast", "write_validation_log"]

LABELS = ("none", "red", "green", "blue", "yellow", "ground", "sky")
"""Material labels of :func:`cast` (index = label)."""

_RGB = {
    "none": (0, 0, 0),
    **DEFAULT_COLOURS,
    "ground": (95, 95, 95),
    "sky": (170, 170, 170),
}


@dataclass(frozen=True)
class PatternScene:
    """The validation pattern (see the module docstring); metres, laser frame."""

    front_m: float = 2.0
    back_m: float = 3.0
    strip_m: float = 0.2
    gap_m: float = 0.15
    n_strips: int = 6
    bottom_m: float = -0.9  # laser x of the lowest bar's lower edge
    length_m: float = 3.0  # bar length along laser z, centred on z = 0
    square_m: float = 0.25
    ground_m: float = 2.2


def cast(
    origin: np.ndarray, dirs: np.ndarray, scene: PatternScene
) -> tuple[np.ndarray, np.ndarray]:
    """Rays from ``origin`` (laser frame, (N,3) unit ``dirs``): hit distance (m, inf for
    none) and the :data:`LABELS` index of what they hit first."""
    n = len(dirs)
    dist = np.full(n, np.inf)
    label = np.full(n, LABELS.index("sky"), dtype=np.int64)
    with np.errstate(divide="ignore", invalid="ignore"):
        # the back wall (y = -back_m) and the ground (x = -ground_m)
        for axis, level in ((1, -scene.back_m), (0, -scene.ground_m)):
            s = (level - origin[axis]) / dirs[:, axis]
            hit = np.isfinite(s) & (s > 0) & (s < dist)
            p = origin + np.nan_to_num(s, posinf=0.0, neginf=0.0)[:, None] * dirs
            if axis == 1:
                # squares centred on the scan plane (no colour edge along the laser line)
                q = scene.square_m
                i = np.floor(p[:, 0] / q + 0.5) + np.floor(p[:, 2] / q + 0.5)
                lab = np.where(i % 2 == 0, LABELS.index("blue"), LABELS.index("yellow"))
            else:
                lab = np.full(n, LABELS.index("ground"))
            dist = np.where(hit, s, dist)
            label = np.where(hit, lab, label)
        # the front bars (y = -front_m)
        s = (-scene.front_m - origin[1]) / dirs[:, 1]
    p = origin + np.nan_to_num(s, posinf=0.0, neginf=0.0)[:, None] * dirs
    pitch = scene.strip_m + scene.gap_m
    k = np.floor((p[:, 0] - scene.bottom_m) / pitch)
    on = (
        np.isfinite(s)
        & (s > 0)
        & (s < dist)
        & (k >= 0)
        & (k < scene.n_strips)
        & ((p[:, 0] - scene.bottom_m - k * pitch) <= scene.strip_m)
        & (np.abs(p[:, 2]) <= scene.length_m / 2)
    )
    lab = np.where(k % 2 == 0, LABELS.index("red"), LABELS.index("green"))
    return np.where(on, s, dist), np.where(on, lab, label)


@dataclass(frozen=True)
class ValidationLog:
    """What :func:`write_validation_log` wrote: the file(s), the true ``camera_to_laser``,
    the ``calibration`` stored in the log (true intrinsics and extrinsic), the scene, and
    per beam the truth: ``beam_label`` (n_steps,) :data:`LABELS` index of what each beam
    hit and ``beam_range`` (n_steps,) its noiseless range (m, inf for none)."""

    files: list[Path]
    truth: Rigid
    calibration: Calibration
    scene: PatternScene
    beam_label: np.ndarray
    beam_range: np.ndarray
    start_ns: int

    def beam_colour(self) -> list[str]:
        """The :data:`LABELS` name of each beam's hit."""
        return [LABELS[i] for i in self.beam_label]


def render(rig: Rig, scene: PatternScene, supersample: int = 2) -> np.ndarray:
    """(H,W,3) float32 BGR image of the scene through the true lens and extrinsic."""
    lens, T, k = rig.lens, rig.camera_to_laser, supersample
    dirs, valid = pixel_rays(lens, k)
    _, label = cast(T.translation, dirs @ T.rotation.T, scene)
    label = np.where(valid, label, LABELS.index("none"))
    table = np.array([_RGB[name][::-1] for name in LABELS], dtype=np.float32)
    img = table[label].reshape(lens.height * k, lens.width * k, 3)
    if k > 1:
        img = img.reshape(lens.height, k, lens.width, k, 3).mean(axis=(1, 3))
    return img.astype(np.float32)


def write_validation_log(
    directory: Path,
    seed: int = 0,
    *,
    duration_s: float = 2.0,
    rig: Rig | None = None,
    scene: PatternScene | None = None,
    blur_px: float = 0.6,
    pixel_noise: float = 2.0,
    jpeg_quality: int = 92,
    start_ns: int = 1_000_000_000_000,
) -> ValidationLog:
    """Write the recording (see the module docstring) into ``directory``; the truth."""
    rig = rig or default_rig()
    scene = scene or PatternScene()
    rng = np.random.default_rng(seed)
    truth = rig.camera_to_laser
    calib = Calibration(cameras={"camera": CameraCalib(rig.lens, truth)})
    writer = open_sim_log(directory, "validation", rig, calib)

    img = np.asarray(cv2.GaussianBlur(render(rig, scene), (0, 0), blur_px), np.float32)
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
            (stamp, "/camera/image/compressed", schemas.compressed_image(frame, "camera"))
        )
    a = rig.angles
    beam_dirs = np.column_stack([np.cos(a), np.sin(a), np.zeros_like(a)])
    beam_range, beam_label = cast(np.zeros(3), beam_dirs, scene)
    for k in range(int(duration_s / rig.scan_period) + 1):
        stamp = start_ns + round(k * rig.scan_period * 1e9)
        r = beam_range + rng.normal(0.0, rig.range_noise, beam_range.shape)
        r = np.where((r > rig.min_range) & (r < rig.max_range), r, np.inf).astype(np.float32)
        events += scan_events(rig, r, k, stamp)
    write_events(writer, events, start_ns, duration_s)
    return ValidationLog(writer.files, truth, calib, scene, beam_label, beam_range, start_ns)


if __name__ == "__main__":  # a quick look: python -m sim.validation_log OUT_DIR
    import sys

    log = write_validation_log(Path(sys.argv[1]))
    names = log.beam_colour()
    print(log.files, {n: names.count(n) for n in LABELS})
