"""`acq calibrate extrinsic` on real data: the KiKuBoy camera + 2D-laser set.

KiKuBoy/2DLaserToCamCalibration (GitHub) publishes 36 board poses of a pinhole camera
(640x480, OpenCV's k1 k2 p1 p2 k3) and a 2-D scanner (0.25 degree steps): per pose
``data/image/N.jpg`` and ``data/scan/N.pcd`` (binary PCD, x y z in metres, the board's
segment cut by hand), their checkerboard (11 x 8 inner corners, 0.04 m squares) and
their result ``result/calibrate_result.yaml``: ``T_laser2cam``, which maps camera points
into the laser frame (their closed form and Ceres fit solve laser -> camera and invert
it), i.e. acq's ``camera_to_laser``; the intrinsics from ``cv2.calibrateCamera`` on the
same images. The repository has no licence, so nothing of it is kept here: give a copy
of it (a checkout, or ``git archive`` of its ``data`` and ``result``) as SOURCE or in
``ACQ_KIKUBOY``.

What it does: writes the set as an acq recording (:func:`write_log`: MCAP through acq's
log writer, each pose held still for a second: its JPEG as sent, twice, and its points
as the ranges of a scan every 0.1 s; a calib.yaml with the published intrinsics), runs
``acq calibrate extrinsic`` on it with the holds as ``--poses`` (:func:`run`), and
prints one JSON line: acq's result against the published ``camera_to_laser`` (rotation
deg, translation mm, and each of the 6 differences over the std acq reports), acq's
reported std, and for comparison plain Levenberg-Marquardt fits (scipy's least_squares,
no robust loss) on the same board planes: over the laser points acq kept
(``lm_segments``) and over every given point (``lm_all_points``), each point counting
alike; and with each pose counting alike (``lm_all_points_per_pose``: KiKuBoy's own
weights); and ``factors``: acq's fit with one thing changed at a time (:func:`factors`).

Run: ``python bench/kikuboy.py SOURCE [--out DIR]`` (default: ``ACQ_KIKUBOY``; neither:
a line saying it was skipped, as under ``make bench``).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from scipy.optimize import least_squares

from acq.calib.board_pose import BoardPose
from acq.camera import calibfile
from acq.camera.calibfile import Calibration, CameraCalib
from acq.camera.camera_models import Pinhole
from acq.geometry.rotations import matrix_from_rotvec, rotation_angle, rotvec_from_matrix
from acq.geometry.transforms import Rigid
from acq.log import schemas
from acq.records import Frame
from acq.sim.board_log import SIM_TIME_BASE, open_sim_log, scan_events, write_events
from acq.sim.world import default_rig

BOARD = "11x8x0.04"  # their config/setting_config.yaml: 11 x 8 inner corners, 0.04 m
CAMERA = "camera"
HOLD_S = 1.0  # each pose held still this long
SCAN_PERIOD_S = 0.1
START_NS = 1_000_000_000_000


@dataclass(frozen=True)
class Published:
    """KiKuBoy's result: ``camera_to_laser`` (their T_laser2cam) and the camera model."""

    camera_to_laser: Rigid
    model: Pinhole


def read_pcd(path: Path) -> np.ndarray:
    """(N,3) float64 points of a binary PCD file with float32 fields x, y, z first."""
    raw = path.read_bytes()
    end = raw.index(b"DATA binary\n") + len(b"DATA binary\n")
    header: dict[str, str] = {}
    for line in raw[:end].decode("ascii").splitlines():
        key, _, value = line.partition(" ")
        header[key] = value
    fields, sizes = header["FIELDS"].split(), [int(s) for s in header["SIZE"].split()]
    counts = [int(c) for c in header["COUNT"].split()] if "COUNT" in header else [1] * len(fields)
    if fields[:3] != ["x", "y", "z"] or sizes[:3] != [4, 4, 4]:
        raise ValueError(f"{path}: expected float32 x y z first, got {fields} {sizes}")
    stride = sum(s * c for s, c in zip(sizes, counts, strict=True))
    n = int(header["POINTS"])
    rows = np.frombuffer(raw[end : end + n * stride], np.uint8).reshape(n, stride)
    return rows[:, :12].copy().view("<f4").astype(np.float64)


def read_published(path: Path) -> Published:
    """``result/calibrate_result.yaml`` (OpenCV FileStorage)."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        T = fs.getNode("T_laser2cam").mat()
        K = fs.getNode("camera_matrix").mat()
        dist = fs.getNode("dist_coeffs").mat().reshape(-1)
    finally:
        fs.release()
    k1, k2, p1, p2, k3 = (float(x) for x in dist)
    fx, fy, cx, cy = (float(K[i, j]) for i, j in ((0, 0), (1, 1), (0, 2), (1, 2)))
    model = Pinhole(640, 480, fx, fy, cx, cy, (k1, k2, p1, p2, k3))
    R, t = np.array(T[:3, :3], dtype=np.float64), np.array(T[:3, 3], dtype=np.float64)
    return Published(Rigid(R, t), model)


def pose_numbers(source: Path) -> list[int]:
    """The poses N with both ``data/image/N.jpg`` and ``data/scan/N.pcd``, in order."""
    images = {int(p.stem) for p in (source / "data" / "image").glob("*.jpg") if p.stem.isdigit()}
    scans = {int(p.stem) for p in (source / "data" / "scan").glob("*.pcd") if p.stem.isdigit()}
    return sorted(images & scans)


def scan_grid(clouds: list[np.ndarray]) -> tuple[float, float, int, list[np.ndarray]]:
    """The scanner's angle_min, angle_increment (rad), steps, and each cloud as ranges (m,
    NaN where the cloud has no point): the beams' angles are on one grid of ~0.25
    degrees, fitted over all points (index by rounding, then a line through them)."""
    angles = [np.arctan2(P[:, 1], P[:, 0]) for P in clouds]
    step0 = float(np.median(np.concatenate([np.diff(np.sort(a)) for a in angles])))
    a0 = min(float(a.min()) for a in angles) - 10 * step0
    idx = np.concatenate([np.rint((a - a0) / step0) for a in angles])
    slope, offset = np.polyfit(idx, np.concatenate(angles), 1)
    n = int(idx.max()) + 11
    out = []
    for P, a in zip(clouds, angles, strict=True):
        r = np.full(n, np.nan, np.float32)
        r[np.rint((a - offset) / slope).astype(int)] = np.hypot(P[:, 0], P[:, 1])
        out.append(r)
    return float(offset), float(slope), n, out


def write_log(source: Path, out: Path) -> tuple[list[Path], Path, str]:
    """The set as an acq recording in ``out``: its MCAP files, the calib.yaml of the
    published intrinsics, and the holds as ``--poses`` takes them (seconds from the
    first scan, 0.1 s in from each end)."""
    pub = read_published(source / "result" / "calibrate_result.yaml")
    numbers = pose_numbers(source)
    clouds = [read_pcd(source / "data" / "scan" / f"{k}.pcd") for k in numbers]
    angle_min, increment, steps, ranges = scan_grid(clouds)
    rig = replace(
        default_rig(), angle_min=angle_min, angle_increment=increment, n_steps=steps,
        scan_period=SCAN_PERIOD_S, time_increment=SCAN_PERIOD_S / 4 / steps,
    )  # fmt: skip
    calib = Calibration(cameras={CAMERA: CameraCalib(pub.model)})
    calib_path = out / "calib.yaml"
    calibfile.save(calib, calib_path)
    writer = open_sim_log(out, "kikuboy", rig, calib)
    events: list[tuple[int, str, bytes]] = []
    hold_ns = round(HOLD_S * 1e9)
    scans_per_hold = round(HOLD_S / SCAN_PERIOD_S)
    topic = f"/{CAMERA}/image/compressed"
    for i, k in enumerate(numbers):
        t0 = START_NS + i * hold_ns
        jpeg = (source / "data" / "image" / f"{k}.jpg").read_bytes()
        for j, at in enumerate((0.3, 0.7)):
            stamp = t0 + round(at * hold_ns)
            frame = Frame(stamp + 2_000_000, stamp, 2 * i + j, 640, 480, jpeg=jpeg)
            msg = schemas.compressed_image(frame, CAMERA, SIM_TIME_BASE.to_log(stamp))
            events.append((stamp, topic, msg))
        for j in range(scans_per_hold):
            seq = i * scans_per_hold + j
            events += scan_events(rig, ranges[i], seq, t0 + round(j * SCAN_PERIOD_S * 1e9))
    write_events(writer, events, START_NS, len(numbers) * HOLD_S)
    holds = ",".join(
        f"{i * HOLD_S + 0.1:.1f}:{(i + 1) * HOLD_S - 0.1:.1f}" for i in range(len(numbers))
    )
    return list(writer.files), calib_path, holds


def run(source: Path, out: Path, *, with_factors: bool = True) -> dict[str, Any]:
    """Convert, calibrate with ``acq calibrate extrinsic`` and compare (module docstring;
    ``with_factors``: the ``factors`` too)."""
    from acq.calib.checkerboard import parse_board
    from acq.calib.extrinsic_log import parse_poses, poses_from_log
    from acq.cli import main
    from acq.log import drive_log

    pub = read_published(source / "result" / "calibrate_result.yaml")
    files, calib_path, holds = write_log(source, out)
    output = out / "calib_out.yaml"
    text = io.StringIO()
    t = time.perf_counter()
    with contextlib.redirect_stdout(text):
        code = main(["calibrate", "extrinsic", *map(str, files), "--intrinsics", str(calib_path),
                     "--board", BOARD, "-o", str(output), "--poses", holds, "--json"])  # fmt: skip
    wall = time.perf_counter() - t
    if code != 0:
        raise RuntimeError(f"acq calibrate extrinsic exited {code}")
    report = json.loads(text.getvalue())
    got = calibfile.load(output).cameras[CAMERA].extrinsics
    assert got is not None
    std = np.r_[np.radians(report["std_rot_deg"]), np.array(report["std_t_mm"]) * 1e-3]
    row: dict[str, Any] = {
        "bench": "kikuboy",
        "poses": len(report["poses"]),
        "poses_kept": len(report["poses"]) - len(report["outliers"]),
        "laser_points": report["n_points"],
        "acq": _against(got, pub.camera_to_laser, std),
        "acq_std_rot_deg": report["std_rot_deg"],
        "acq_std_t_mm": report["std_t_mm"],
        "acq_rms_mm": report["rms_mm"],
        "wall_s": round(wall, 2),
    }
    # the same board planes and laser points as the command, through its own functions
    log = drive_log.read_log(files, calib=calibfile.load(calib_path))
    data = poses_from_log(
        log, pub.model, parse_board(BOARD), parse_poses(holds, int(log.scan_ns[0]))
    )
    segments = [p.pose for p in data if p.pose is not None]
    numbers = pose_numbers(source)
    everything = [
        replace(p, points=read_pcd(source / "data" / "scan" / f"{k}.pcd"))
        for p, k in zip(segments, numbers, strict=True)
    ]
    for name, poses, per_pose in (
        ("lm_segments", segments, False),
        ("lm_all_points", everything, False),
        ("lm_all_points_per_pose", everything, True),
    ):
        row[name] = _against(plain_lm(poses, pub.camera_to_laser, per_pose), pub.camera_to_laser)
    if with_factors:
        row["factors"] = factors(source, pub, segments, everything)
    return row


def factors(
    source: Path, pub: Published, segments: list[BoardPose], everything: list[BoardPose]
) -> dict[str, Any]:
    """acq's calibration (:func:`acq.calib.extrinsic.calibrate`, as the command) with one
    thing changed at a time, each against the published: the board planes from
    cv2.solvePnP on the same corners with the published intrinsics (and how far they are
    from acq's: normal deg, distance mm), every given laser point instead of the board
    segment acq picked, the planes taken as exact with each pose counting alike (acq's
    first stage, KiKuBoy's weights), and no robust loss."""
    from acq.calib.checkerboard import detect_corners, parse_board
    from acq.calib.extrinsic import calibrate

    spec = parse_board(BOARD)
    m = pub.model
    K = np.array([[m.fx, 0.0, m.cx], [0.0, m.fy, m.cy], [0.0, 0.0, 1.0]])
    cv_planes, normal_deg, distance_mm = [], [], []
    for p, k in zip(segments, pose_numbers(source), strict=True):
        gray = cv2.imread(str(source / "data" / "image" / f"{k}.jpg"), cv2.IMREAD_GRAYSCALE)
        uv = detect_corners(gray, spec)
        assert uv is not None
        _, rvec, tvec = cv2.solvePnP(spec.object_points(), uv, K, np.array(m.dist))
        n = cv2.Rodrigues(rvec)[0][:, 2]
        d = float(n @ tvec.reshape(3))
        cv_planes.append(replace(p, normal=n, distance=d))
        normal_deg.append(math.degrees(math.acos(min(1.0, float(n @ p.normal)))))
        distance_mm.append(abs(d - p.distance) * 1e3)
    ref = pub.camera_to_laser
    return {
        "acq": _against(calibrate(segments).camera_to_laser, ref),
        "planes_cv2_solvepnp": _against(calibrate(cv_planes).camera_to_laser, ref),
        "planes_max_diff": {"normal_deg": max(normal_deg), "distance_mm": max(distance_mm)},
        "all_given_points": _against(calibrate(everything).camera_to_laser, ref),
        "exact_planes_poses_alike": _against(
            calibrate(segments, plane_errors=False).camera_to_laser, ref
        ),
        "no_robust_loss": _against(calibrate(segments, loss="linear").camera_to_laser, ref),
    }


def plain_lm(poses: list[BoardPose], start: Rigid, per_pose: bool) -> Rigid:
    """scipy's Levenberg-Marquardt on the point-to-plane residuals ``n . R^T (P - t) - d``
    (m), no robust loss; ``per_pose``: each pose's residuals scaled by 1/sqrt(count)."""

    def residuals(x: np.ndarray) -> np.ndarray:
        R = matrix_from_rotvec(x[:3]) @ start.rotation
        out = []
        for p in poses:
            r = (p.points - x[3:]) @ (R @ p.normal) - p.distance
            out.append(r / math.sqrt(len(r)) if per_pose else r)
        return np.concatenate(out)

    x = least_squares(residuals, np.r_[np.zeros(3), start.translation], method="lm").x
    return Rigid(matrix_from_rotvec(x[:3]) @ start.rotation, x[3:])


def _against(got: Rigid, ref: Rigid, std: np.ndarray | None = None) -> dict[str, Any]:
    """Rotation (deg) and translation (mm) of ``got`` against ``ref``; with ``std`` (the 6
    reported: left rotation vector rad, translation m) each difference over its std."""
    dR = got.rotation @ ref.rotation.T
    e = np.r_[rotvec_from_matrix(dR), got.translation - ref.translation]
    out: dict[str, Any] = {
        "rot_deg": round(math.degrees(rotation_angle(dR)), 4),
        "t_mm": round(float(np.linalg.norm(e[3:])) * 1e3, 3),
        "t_diff_mm": [round(float(x) * 1e3, 3) for x in e[3:]],
    }
    if std is not None:
        out["diff_over_std"] = [round(float(x), 2) for x in e / std]
    return out


def source_dir(given: str | None) -> Path | None:
    """SOURCE, else ``ACQ_KIKUBOY``; None when neither names a folder with the set."""
    text = given or os.environ.get("ACQ_KIKUBOY", "")
    if not text:
        return None
    path = Path(text)
    ok = (path / "result" / "calibrate_result.yaml").is_file() and (path / "data" / "scan").is_dir()
    return path if ok else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("source", nargs="?", help="a copy of KiKuBoy/2DLaserToCamCalibration "
                    "(default: ACQ_KIKUBOY)")  # fmt: skip
    ap.add_argument(
        "--out", type=Path, help="folder for the log and calib files (default: temporary)"
    )
    args = ap.parse_args()
    given = args.source or os.environ.get("ACQ_KIKUBOY", "")
    if not given:  # make bench runs every script: say why there is no figure
        print(json.dumps({"bench": "kikuboy", "skipped": "ACQ_KIKUBOY not set (the set is "
                          "not redistributable: no licence)"}), flush=True)  # fmt: skip
        return
    source = source_dir(given)
    if source is None:
        what = "SOURCE" if args.source else "ACQ_KIKUBOY"
        print(f"bench/kikuboy.py: {what} {given}: not a copy of KiKuBoy/2DLaserToCamCalibration "
              "(no data/scan or result/calibrate_result.yaml)", file=sys.stderr)  # fmt: skip
        sys.exit(2)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        print(json.dumps(run(source, args.out)), flush=True)
        return
    with tempfile.TemporaryDirectory() as tmp:
        print(json.dumps(run(source, Path(tmp))), flush=True)


if __name__ == "__main__":
    main()
