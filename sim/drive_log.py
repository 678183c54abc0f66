"""A simulated drive recorded as the recorder writes it, with the truth.

The simulated rig (``acq.sim.world.default_rig``: UTM-30LX geometry and one 185-degree
fisheye, or ``default_rig(cameras=2)``: a left and a right one) drives the synthetic street
(with the validation pattern at ``pattern_at`` m on the left) in the lane at ``lane_y`` m,
at ``speed_kmh``, along a gentle curve, with body vibration. Everything a recording carries
is simulated, and the log holds only what a recorder would have:

- scans: each cast step by step from the laser's pose at its own time, with a return
  strength per point (:func:`acq.sim.sensors.return_strength`, 5 % noise); the scanner's
  millisecond clock (24 bits) runs ``scanner_drift_ppm`` fast; each telegram arrives
  ``scanner_latency_s`` plus an exponential jitter after the scan's end; the recorded
  stamp is what the recorder computes online (:class:`acq.time.clocksync.DeviceClock` on the
  ticks, minus the configured latency, which is the true constant part);
- frames, for every camera of the rig on topics ``/<name>/image/compressed`` and
  ``/acq/timing/<name>``: exposed on the camera's own grid (``camera_drift_ppm``, each
  camera's clock phase a few ms after the previous one's), ray-cast through its TRUE lens
  with its photometry at that time, JPEG; each arrives the camera's latency + half its
  exposure + an exponential jitter (one stream per camera: a late frame delays the next)
  after its middle of exposure, and is stamped receipt minus the configured latency — by
  default NOT the true value (the configuration does not know the camera's latency);
- odometry: the vehicle's true speed and yaw rate at 50 Hz on ``/vehicle/odometry``,
  stamped on the host clock; optionally GNSS fixes on ``/gnss/fix`` (RTK-like noise);
- 1 Hz clock pairs; metadata: the scanner's geometry, ``device.<camera>``, the TRUE
  calibration of every camera.

:class:`DriveTruth` holds the truth: the street, trajectory and rig, the true time of
every scan's point 0, every scan's noise-free world hit points, per camera every frame's
middle of exposure, stamp and gains (:class:`CameraTruth`), and which camera really sees
which point (``visible``). Host times are ns from ``start_ns``; the simulator's clock is
seconds from the drive's start.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from acq.camera import calibfile
from acq.camera.calibfile import Calibration, CameraCalib
from acq.geometry.geodesy import WorldFrame
from acq.log import schemas
from acq.log.writer import LogWriter
from acq.motion import Trajectory as MotionTrajectory
from acq.records import Fix, Frame, Odometry, Scan
from acq.sim.board_log import SIM_TIME_BASE
from acq.sim.nmea_device import DEFAULT_ORIGIN
from acq.sim.sensors import (
    camera_to_world,
    render_frame_truth,
    render_scan,
    return_strength,
    seen_in_frame,
)
from acq.sim.world import Rig, Street, Trajectory, default_rig
from acq.time.clocksync import DeviceClock

if TYPE_CHECKING:
    from acq.cloud.job import Job

__all__ = [
    "SINGLE_CAMERA_LATENCY_S",
    "CameraTruth",
    "DriveTruth",
    "visibility_shares",
    "write_drive_log",
]

SINGLE_CAMERA_LATENCY_S = 0.030  # a one-camera rig's latency unless told (the old default)
FIRST_FRAME_S = 0.017  # the first camera's first middle of exposure, s
CLOCK_PHASE_STEP_S = 0.007  # each further camera's frame grid starts this much later, s


@dataclass(frozen=True)
class CameraTruth:
    """One camera's frames in the drive: ``frame_t_s`` (F,) true middle of exposure, s;
    ``frame_stamp_ns`` (F,) the recorded stamps; ``gains`` (F,3) BGR its photometry at
    each frame (:meth:`acq.sim.world.Photometry.gains`); ``latency_true_s`` the mean of
    receipt minus middle of exposure and ``latency_configured_s`` what its driver
    subtracted (s)."""

    name: str
    frame_t_s: np.ndarray
    frame_stamp_ns: np.ndarray
    gains: np.ndarray
    latency_true_s: float
    latency_configured_s: float


@dataclass(frozen=True)
class DriveTruth:
    """What :func:`write_drive_log` wrote and the truth behind it (module docstring).

    ``frame_t_s``, ``frame_stamp_ns`` and ``config['camera_latency_*']`` are the first
    camera's; ``cameras`` every camera's, in the rig's order. ``visible`` (S, N, C): whether
    camera c (``camera_names[c]``) really sees scan point (s, n) in its frame nearest the
    point's time (:func:`acq.sim.sensors.seen_in_frame`; False where there is no hit)."""

    files: list[Path]
    street: Street
    trajectory: Trajectory
    rig: Rig
    calibration: Calibration  # the true one
    start_ns: int  # host ns of the drive's t = 0
    scan_t0_s: np.ndarray  # (S,) true time of each scan's point 0, s
    scan_stamp_ns: np.ndarray  # (S,) the recorded (online) stamps
    points: np.ndarray  # (S, N, 3) float32 noise-free world hit points (NaN none)
    materials: np.ndarray  # (S, N) uint8 acq.sim.world.Material of each hit
    colours: np.ndarray  # (S, N, 3) uint8 BGR surface colour of each hit
    frame_t_s: np.ndarray  # (F,) true middle of exposure, s
    frame_stamp_ns: np.ndarray  # (F,) the recorded stamps
    config: dict[str, float] = field(default_factory=dict)
    cameras: dict[str, CameraTruth] = field(default_factory=dict)
    visible: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 0), dtype=bool))

    @property
    def camera_names(self) -> tuple[str, ...]:
        """The cameras in the order of ``visible``'s last axis (the rig's)."""
        return tuple(self.cameras)

    def point_t_s(self) -> np.ndarray:
        """(S, N) true time of every scan point, s."""
        steps = self.rig.time_increment * np.arange(self.points.shape[1])
        times: np.ndarray = self.scan_t0_s[:, None] + steps[None, :]
        return times

    def host_trajectory(self, step_s: float = 1e-3) -> MotionTrajectory:
        """The true trajectory as `acq colorize --trajectory` takes it: vehicle poses
        every ``step_s`` s on the host clock (ns), from a second before the drive to a
        second after."""
        t_s = np.arange(-1.0, self.config["seconds"] + 1.0, step_s)
        R, p = self.trajectory.poses(t_s)
        return MotionTrajectory(self.start_ns + np.rint(t_s * 1e9).astype(np.int64), R, p)

    def true_pixels(
        self,
        scan: np.ndarray,
        step: np.ndarray,
        frame_stamp_ns: np.ndarray,
        camera: str | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Where the noise-free hits of points (``scan``, ``step``) fall in camera
        ``camera``'s (None: the first's) frames with recorded stamps ``frame_stamp_ns``
        (true lens, true pose at the frame's true time): (N,2) px and (N,) valid (also
        False for an unknown frame or no hit)."""

        name = self.rig.camera(camera).name
        cam = self.cameras[name]
        scan, step = np.asarray(scan, np.int64), np.asarray(step, np.int64)
        k = np.clip(np.searchsorted(cam.frame_stamp_ns, frame_stamp_ns), 0,
                    cam.frame_stamp_ns.size - 1)  # fmt: skip
        known = cam.frame_stamp_ns[k] == frame_stamp_ns
        P = self.points[scan, step].astype(np.float64)
        uv = np.full((scan.size, 2), np.nan)
        valid = np.zeros(scan.size, dtype=bool)
        lens = self.rig.camera(name).lens
        for j in np.unique(k[known]):
            sel = np.flatnonzero(known & (k == j))
            pose = camera_to_world(self.trajectory, self.rig, float(cam.frame_t_s[j]), name)
            uv[sel], valid[sel] = lens.project(pose.inverse().apply(P[sel]))
        valid &= np.isfinite(P).all(axis=1)
        return uv, valid

    def time_offsets_s(self, job: Job) -> dict[str, float]:
        """Each camera's true time offset (camera minus laser time, s) as ``job`` (of this
        drive's log, :func:`acq.cloud.job.prepare`) re-timed the stamps: the re-timed
        frames' mean error minus the re-timed scans'."""
        from acq.cloud.job import remap

        scans = remap(job.scan_old, job.scan_new, self.scan_stamp_ns)
        scan_err = float(np.mean(scans - (self.start_ns + self.scan_t0_s * 1e9)))
        out = {}
        for cj in job.cameras:
            c = self.cameras[cj.name]
            frames = remap(cj.frame_old, cj.frame_new, c.frame_stamp_ns)
            frame_err = float(np.mean(frames - (self.start_ns + c.frame_t_s * 1e9)))
            out[cj.name] = (frame_err - scan_err) * 1e-9
        return out

    def distances(
        self,
        scan: np.ndarray,
        step: np.ndarray,
        xyz: np.ndarray,
        enu_origin: tuple[float, float, float] | None = None,
    ) -> np.ndarray:
        """Distance (m) of placed points ``xyz`` (N,3) to the noise-free hits of their
        (``scan``, ``step``), NaN where there is none; ``xyz`` in the ENU frame at
        ``enu_origin`` (lat °, lon °, h m; a cloud placed by GNSS: its first fix), or
        None: the street's own frame."""
        P = self.points[np.asarray(scan, np.int64), np.asarray(step, np.int64)]
        P = P.astype(np.float64)
        if enu_origin is not None:
            P = P - WorldFrame("enu", DEFAULT_ORIGIN).from_geodetic(*map(np.array, enu_origin))
        d: np.ndarray = np.linalg.norm(np.asarray(xyz, np.float64) - P, axis=1)
        return d


def _geometry(rig: Rig) -> dict[str, float]:
    return {
        "angle_min": rig.angle_min,
        "angle_increment": rig.angle_increment,
        "n_points": rig.n_steps,
        "time_increment": rig.time_increment,
        "scan_period": rig.scan_period,
        "range_min": rig.min_range,
        "range_max": rig.max_range,
        "stamp_offset_s": 0.0,
    }


def write_drive_log(
    directory: Path,
    seconds: float = 60.0,
    *,
    seed: int = 0,
    speed_kmh: float = 20.0,
    lane_y: float = 1.5,
    pattern_at: float | None = 60.0,
    curve_amplitude: float = 0.8,
    vibration_rad: float = 0.002,
    scanner_drift_ppm: float = 30.0,
    scanner_latency_s: float = 0.002,
    scanner_jitter_s: float = 0.001,
    camera_drift_ppm: float = -20.0,
    camera_latency_s: float | None = SINGLE_CAMERA_LATENCY_S,
    camera_jitter_s: float = 0.003,
    configured_camera_latency_s: float | Mapping[str, float] | None = 0.025,
    odometry_hz: float = 50.0,
    odometry_span_s: tuple[float, float] | None = None,
    jpeg_quality: int = 90,
    intensity_noise: float = 0.05,
    intensities: bool = True,
    gnss_hz: float = 0.0,
    gnss_noise_m: float = 0.02,
    gnss_edit: Callable[[int, Fix], Fix] | None = None,
    start_ns: int = 2_000_000_000_000,
    rig: Rig | None = None,
) -> DriveTruth:
    """Write the drive (module docstring) into ``directory``; returns the truth.

    ``camera_latency_s``: a one-camera rig's latency (end of exposure -> available, s;
    None: its :class:`acq.sim.world.RigCamera` ``latency_s``); a rig of several cameras
    uses each camera's ``latency_s`` (change one with ``Rig.with_camera``), and
    ``camera_latency_s`` must then be None or left at its default (ValueError).
    ``configured_camera_latency_s`` is what the recording's camera drivers subtract: one
    value for every camera, a mapping camera name -> value naming every camera, or None:
    each camera's true mean (its latency + half its exposure + the jitter's mean);
    ``odometry_span_s`` (start, end) s limits the odometry (default: the whole drive);
    ``intensity_noise``: the relative spread of the scans' return strengths;
    ``intensities=False``: scans without them (a scanner asked for ranges only);
    ``gnss_hz`` > 0: GNSS fixes of the true position with ``gnss_noise_m`` (m) noise;
    ``gnss_edit(k, fix)``: the fix written as fix number k (an outlier, say).
    """
    rig = rig or default_rig()
    latencies = _latencies(rig, camera_latency_s)
    configured = _configured(rig, latencies, camera_jitter_s, configured_camera_latency_s)
    rng = np.random.default_rng(seed)
    intensity_rng = np.random.default_rng(
        [seed, 1]
    )  # its own stream: the other draws do not depend on it
    length = speed_kmh / 3.6 * seconds + 80.0
    street = Street.generate(seed, length_m=length, pattern_at=pattern_at)
    traj = Trajectory(
        speed=speed_kmh / 3.6, x0=0.0, y0=lane_y, curve_amplitude=curve_amplitude,
        curve_wavelength=90.0, vibration_rad=vibration_rad, seed=seed,
    )  # fmt: skip
    calib = Calibration(
        cameras={
            c.name: CameraCalib(c.lens, c.camera_to_laser, method="truth") for c in rig.cameras
        },
        laser_to_vehicle=rig.laser_to_vehicle,
    )
    metadata = {"device.laser": {"driver": "hokuyo", "geometry": json.dumps(_geometry(rig))}}
    metadata |= {f"device.{name}": {"driver": "sim"} for name in rig.camera_names}
    metadata["calibration"] = {"yaml": calibfile.dump(calib)}
    writer = LogWriter(
        directory, prefix="drive", metadata=metadata, split_s=seconds + 600.0,
        time_base=SIM_TIME_BASE,
    )  # fmt: skip
    to_log = SIM_TIME_BASE.to_log
    for topic, schema in (
        ("/laser/scan", "foxglove.LaserScan"),
        ("/laser/raw", "acq.RawTelegram"),
        ("/acq/timing/laser", "acq.Timing"),
        *(
            channel
            for name in rig.camera_names
            for channel in (
                (f"/{name}/image/compressed", "foxglove.CompressedImage"),
                (f"/acq/timing/{name}", "acq.Timing"),
            )
        ),
        ("/acq/clock", "acq.Clock"),
    ):
        writer.add_channel(topic, schemas.SCHEMAS[schema])
    if odometry_hz > 0:
        writer.add_channel("/vehicle/odometry", schemas.SCHEMAS["acq.Odometry"])
    if gnss_hz > 0:
        writer.add_channel("/gnss/fix", schemas.SCHEMAS["foxglove.LocationFix"])

    def host(t: float) -> int:
        return start_ns + round(t * 1e9)

    events: list[tuple[int, int, str, bytes]] = []  # (log time, stamp, topic, payload)
    # --- scans
    period = rig.scan_period / (1 + scanner_drift_ppm * 1e-6)  # in host seconds
    n_scans = int(seconds / period)
    clock = DeviceClock(1000.0, 24)
    tick0 = 123_456
    scan_t0 = np.arange(n_scans) * period + 0.01
    pts = np.full((n_scans, rig.n_steps, 3), np.nan, dtype=np.float32)
    mats = np.zeros((n_scans, rig.n_steps), dtype=np.uint8)
    cols = np.zeros((n_scans, rig.n_steps, 3), dtype=np.uint8)
    scan_stamps = np.zeros(n_scans, dtype=np.int64)
    recv_prev = 0
    for k, t0 in enumerate(scan_t0.tolist()):
        st = render_scan(street, traj, rig, t0, rng)
        pts[k], mats[k], cols[k] = st.points, st.material, st.colours
        strength = return_strength(st.ranges, st.colours, intensity_rng, intensity_noise)
        tick = (tick0 + math.floor(t0 * 1000.0 * (1 + scanner_drift_ppm * 1e-6))) % (1 << 24)
        end = t0 + rig.time_increment * (rig.n_steps - 1)
        recv = max(host(end + scanner_latency_s + rng.exponential(scanner_jitter_s)),
                   recv_prev + 100_000)  # fmt: skip
        recv_prev = recv
        clock.update(tick, recv)
        # the recorder: the tick through the clock, minus the constant latency it knows
        latency_const = scanner_latency_s + rig.time_increment * (rig.n_steps - 1)
        stamp = clock.to_host_ns(tick) - round(latency_const * 1e9)
        scan_stamps[k] = stamp
        scan = Scan(
            ranges=st.ranges,
            intensities=strength.astype(np.float32) if intensities else np.zeros(0, np.float32),
            angle_min=rig.angle_min,
            angle_increment=rig.angle_increment, time_increment=rig.time_increment,
            scan_period=rig.scan_period, recv_ns=recv, start_ns=stamp, sequence=k,
            device_ticks=(tick,),
        )  # fmt: skip
        timing = schemas.timing(recv_ns=recv, stamp_ns=stamp, device_ticks=(tick,), sequence=k)
        raw = schemas.raw_telegram(device="laser", data=b"", device_ticks=(tick,), sequence=k,
                                   recv_ns=recv, stamp_ns=stamp)  # fmt: skip
        events += [
            (recv, stamp, "/laser/scan", schemas.laser_scan(scan, "laser", to_log(stamp))),
            (recv, stamp, "/laser/raw", raw),
            (recv, stamp, "/acq/timing/laser", timing),
        ]
    # --- frames, camera by camera; the first draws its jitter from the drive's stream
    point_t = (scan_t0[:, None] + rig.time_increment * np.arange(rig.n_steps)).ravel()
    point_order = np.argsort(point_t, kind="stable")
    flat_points = pts.reshape(-1, 3)
    visible = np.zeros((n_scans * rig.n_steps, len(rig.cameras)), dtype=bool)
    cameras: dict[str, CameraTruth] = {}
    fperiod = 1.0 / rig.fps / (1 + camera_drift_ppm * 1e-6)
    for c, cam in enumerate(rig.cameras):
        cam_rng = rng if c == 0 else np.random.default_rng([seed, 3, c])
        first = FIRST_FRAME_S + c * CLOCK_PHASE_STEP_S
        n_frames = int((seconds - 0.05 - c * CLOCK_PHASE_STEP_S) / fperiod)
        frame_t = first + np.arange(n_frames) * fperiod
        # each point is judged in the frame nearest its time
        edges = np.searchsorted(point_t[point_order], (frame_t[:-1] + frame_t[1:]) / 2)
        bounds = np.concatenate([[0], edges, [point_t.size]])
        frame_stamps = np.zeros(n_frames, dtype=np.int64)
        gains = np.zeros((n_frames, 3))
        recv_prev = 0
        for k, t in enumerate(frame_t.tolist()):
            ft = render_frame_truth(street, traj, rig, t, cam.name)
            gains[k] = ft.gains
            near = point_order[bounds[k] : bounds[k + 1]]
            visible[near, c] = seen_in_frame(flat_points[near], ft, traj, rig, cam.name)
            ok, buf = cv2.imencode(".jpg", ft.image, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
            if not ok:
                raise RuntimeError("JPEG encoding failed")
            late = latencies[c] + cam.exposure / 2 + cam_rng.exponential(camera_jitter_s)
            recv = max(host(t + late), recv_prev + 1_000_000)
            recv_prev = recv
            stamp = recv - round(configured[c] * 1e9)
            frame_stamps[k] = stamp
            frame = Frame(recv, stamp, k, cam.lens.width, cam.lens.height, jpeg=buf.tobytes())
            timing = schemas.timing(recv_ns=recv, stamp_ns=stamp, sequence=k, received=k + 1)
            image = schemas.compressed_image(frame, cam.name, to_log(stamp))
            events += [
                (recv, stamp, f"/{cam.name}/image/compressed", image),
                (recv, stamp, f"/acq/timing/{cam.name}", timing),
            ]
        cameras[cam.name] = CameraTruth(
            name=cam.name,
            frame_t_s=frame_t,
            frame_stamp_ns=frame_stamps,
            gains=gains,
            latency_true_s=latencies[c] + cam.exposure / 2 + camera_jitter_s,
            latency_configured_s=configured[c],
        )
    # --- odometry (true speed and yaw rate, by central differences of the trajectory)
    if odometry_hz > 0:
        first, last = odometry_span_s or (0.0, seconds + 0.2)
        ts = np.arange(first, last, 1.0 / odometry_hz)
        h = 1e-3
        _, pa = traj.poses(ts - h)
        _, pb = traj.poses(ts + h)
        Ra, _ = traj.poses(ts - h)
        Rb, _ = traj.poses(ts + h)
        speed = np.linalg.norm(pb - pa, axis=1) / (2 * h)
        yaw_a = np.arctan2(Ra[:, 1, 0], Ra[:, 0, 0])
        yaw_b = np.arctan2(Rb[:, 1, 0], Rb[:, 0, 0])
        yaw_rate = np.angle(np.exp(1j * (yaw_b - yaw_a))) / (2 * h)
        for t, v, w in zip(ts.tolist(), speed.tolist(), yaw_rate.tolist(), strict=True):
            stamp = host(t)
            recv = stamp + 300_000
            odo = Odometry(recv_ns=recv, stamp_ns=stamp, speed=v, yaw_rate=w)
            events.append((recv, stamp, "/vehicle/odometry", schemas.odometry(odo)))
    # --- GNSS: the vehicle's true position (the antenna at its origin), street x east and
    # y north of ORIGIN, with Gaussian noise; stamped at the fix instant, received later
    if gnss_hz > 0:
        gnss_rng = np.random.default_rng([seed, 2])
        ts = np.arange(0.0, seconds + 0.2, 1.0 / gnss_hz)
        _, pos = traj.poses(ts)
        noisy = pos + gnss_rng.normal(0.0, gnss_noise_m, pos.shape)
        geo = WorldFrame("enu", DEFAULT_ORIGIN).to_geodetic(noisy)
        for k, (t, lat, lon, h) in enumerate(
            zip(ts.tolist(), *(a.tolist() for a in geo), strict=True)
        ):
            stamp = host(t)
            fix = Fix(recv_ns=stamp + 45_000_000, utc_s=to_log(stamp) * 1e-9,
                      latitude=lat, longitude=lon, altitude=h, quality=4, satellites=14,
                      hdop=0.7)  # fmt: skip
            if gnss_edit is not None:
                fix = gnss_edit(k, fix)
            events.append(
                (fix.recv_ns, stamp, "/gnss/fix", schemas.location_fix(fix, to_log(stamp)))
            )
    # --- clock pairs, then everything in receipt order
    for k in range(int(seconds) + 2):
        stamp = host(float(k))
        pair = schemas.clock(realtime_ns=to_log(stamp), monotonic_ns=stamp)
        events.append((stamp, stamp, "/acq/clock", pair))
    events.sort(key=lambda e: e[0])
    try:
        for log_time, stamp, topic, payload in events:
            writer.write(topic, payload, log_time, stamp)
    finally:
        writer.close()
    first_cam = cameras[rig.camera_names[0]]
    return DriveTruth(
        files=writer.files,
        street=street,
        trajectory=traj,
        rig=rig,
        calibration=calib,
        start_ns=start_ns,
        scan_t0_s=scan_t0,
        scan_stamp_ns=scan_stamps,
        points=pts,
        materials=mats,
        colours=cols,
        frame_t_s=first_cam.frame_t_s,
        frame_stamp_ns=first_cam.frame_stamp_ns,
        config={
            "seconds": seconds,
            "speed_kmh": speed_kmh,
            "camera_latency_true_s": first_cam.latency_true_s,
            "camera_latency_configured_s": first_cam.latency_configured_s,
        },
        cameras=cameras,
        visible=visible.reshape(n_scans, rig.n_steps, len(rig.cameras)),
    )


def _latencies(rig: Rig, camera_latency_s: float | None) -> list[float]:
    """Each camera's latency, s (``write_drive_log``'s ``camera_latency_s``)."""
    if len(rig.cameras) == 1:
        return [rig.cameras[0].latency_s if camera_latency_s is None else camera_latency_s]
    if camera_latency_s not in (None, SINGLE_CAMERA_LATENCY_S):
        raise ValueError(
            "camera_latency_s is a one-camera rig's; with several cameras each camera's "
            "RigCamera.latency_s is used (change one with Rig.with_camera)"
        )
    return [c.latency_s for c in rig.cameras]


def _configured(
    rig: Rig,
    latencies: list[float],
    jitter_s: float,
    configured: float | Mapping[str, float] | None,
) -> list[float]:
    """Each camera's configured latency, s (``write_drive_log``'s
    ``configured_camera_latency_s``)."""
    if configured is None:
        return [
            lat + c.exposure / 2 + jitter_s for c, lat in zip(rig.cameras, latencies, strict=True)
        ]
    if isinstance(configured, Mapping):
        missing = [n for n in rig.camera_names if n not in configured]
        if missing:
            raise ValueError(f"configured_camera_latency_s names no latency for {missing}")
        return [float(configured[n]) for n in rig.camera_names]
    return [float(configured)] * len(rig.cameras)


def visibility_shares(truth: DriveTruth) -> dict[str, float]:
    """Of the scan points with a hit, the share every combination of cameras sees:
    ``'left'`` (that camera only), ``'left+right'``, ``'none'``... (0 to 1)."""
    hit = np.isfinite(truth.points).all(axis=2)
    seen = truth.visible[hit]
    names = truth.camera_names
    codes = seen.astype(np.int64) @ (1 << np.arange(len(names)))
    counts = np.bincount(codes, minlength=1 << len(names))
    shares = {}
    for code, n in enumerate(counts.tolist()):
        who = "+".join(name for i, name in enumerate(names) if code >> i & 1) or "none"
        shares[who] = n / max(seen.shape[0], 1)
    return shares


def main(argv: list[str] | None = None) -> None:
    """Write a drive and its true calib.yaml into OUT_DIR (a quick look, not a command)."""
    parser = argparse.ArgumentParser(prog="python -m acq.sim.drive_log", description=main.__doc__)
    parser.add_argument("out_dir", type=Path)
    parser.add_argument("seconds", nargs="?", type=float, default=10.0)
    parser.add_argument("--cameras", type=int, choices=(1, 2, 3), default=1)
    args = parser.parse_args(argv)
    if not 0 < args.seconds < math.inf:
        parser.error(f"expected seconds > 0, got {args.seconds}")
    args.out_dir.mkdir(parents=True, exist_ok=True)
    truth = write_drive_log(args.out_dir, args.seconds, rig=default_rig(cameras=args.cameras))
    calibfile.save(truth.calibration, args.out_dir / "calib.yaml")
    frames = ", ".join(f"{n} {c.frame_t_s.size}" for n, c in truth.cameras.items())
    print(*(str(f) for f in truth.files), f"{truth.scan_t0_s.size} scans; frames: {frames}")
    shares = visibility_shares(truth)
    print("points with a hit seen by: " + ", ".join(f"{k} {v:.1%}" for k, v in shares.items()))


if __name__ == "__main__":
    main()
