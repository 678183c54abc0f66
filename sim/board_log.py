"""A simulated camera–laser calibration recording (MCAP), with the truth (paper §3.2).

A checkerboard (default 9x7 inner corners of 0.1 m, a white margin) is held still in
``n_poses`` poses per camera of the rig (placed as :func:`acq.sim.board_poses.simulate`
does for that camera: 1–2.5 m from the scanner, facing the camera, tilted up to ±30
degrees, cut by the scan plane) for ``hold_s`` seconds each and carried from one to the
next in ``move_s`` seconds: the first camera's poses, then the next camera's. Behind it
a wall (``wall_m`` m to the camera's side of the vehicle; with several cameras one on
each side) and the ground, so the scanner sees more than the board.

Several cameras (``default_rig(cameras=2)``): every camera films the whole recording
(the board in its own poses, and wherever else its lens sees it) on
``/<name>/image/compressed``, its frames at its own phase of the frame period, with
``/acq/timing/<name>`` records (sequence, receipt at mid-exposure + half the exposure +
its latency). A single-camera rig writes what it always did: ``/camera/image/compressed``
(its camera's name), no timing records.

Sensors (``acq.sim.world.default_rig``, the truth): the camera at ``fps`` Hz, every pixel
ray-cast through the TRUE lens (2x2 supersampled for still poses), blurred (sigma
``blur_px``), grey noise, JPEG; the scanner at 1 / ``scan_period`` Hz with the UTM-30LX
geometry (-135..135 degrees, 0.25 degree steps, laser frame), 10 mm range noise. Topics as
the recorder writes them: ``/laser/scan`` (foxglove.LaserScan stamped at point 0),
``/laser/raw``, ``/<camera>/image/compressed`` (stamped at mid-exposure), ``/acq/clock``;
metadata ``device.laser`` (geometry JSON), ``device.<camera>`` and ``calibration`` (the
true intrinsics of every camera, no camera_to_laser). Times are host monotonic ns from ``start_ns``.

World frame = the laser frame (x = up, y = vehicle right, z = vehicle forward).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from acq.camera import calibfile
from acq.camera.calibfile import Calibration, CameraCalib
from acq.camera.camera_models import CameraModel
from acq.geometry.rotations import matrix_from_rotvec, rotvec_from_matrix
from acq.geometry.transforms import Rigid
from acq.log import schemas
from acq.log.timebase import TimeBase
from acq.log.writer import LogWriter
from acq.records import Frame, Scan
from acq.sim.board_poses import Checkerboard, simulate
from acq.sim.world import Rig, RigCamera, default_rig

# The simulated logs' host monotonic times map to UTC through this one offset (their
# /acq/clock pairs and their UTC log times alike): 2027-01-15 08:00:00 UTC at monotonic 0.
SIM_TIME_BASE = TimeBase(True, 1_800_000_000 * 10**9)

__all__ = ["BoardLog", "board_at", "pixel_rays", "render_frame", "simulate_scan", "write_board_log"]

BOARD = Checkerboard(cols=10, rows=8, square=0.1, width=1.2, height=1.0)  # 9x7 inner
_WHITE, _BLACK, _WALL, _GROUND, _SKY = 225.0, 35.0, 140.0, 95.0, 170.0


@dataclass(frozen=True)
class BoardLog:
    """What :func:`write_board_log` wrote: the file(s), the first camera's true
    ``camera_to_laser`` (``truths``: every camera's, by name), the ``boards``
    (board_to_laser of each pose), the still intervals (host ns), the board (``spec`` as
    ``acq calibrate extrinsic --board`` takes it), the calibration stored in the log
    (true intrinsics) and ``placed_for``: the camera each pose was placed for."""

    files: list[Path]
    truth: Rigid
    boards: list[Rigid]
    holds: list[tuple[int, int]]
    board: Checkerboard
    spec: str
    calibration: Calibration
    start_ns: int
    truths: dict[str, Rigid]
    placed_for: tuple[str, ...]

    @property
    def cameras(self) -> tuple[str, ...]:
        """The cameras' names, in the rig's order."""
        return tuple(self.truths)


def _checker(board: Checkerboard, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Grey level of board-frame points (m): squares centred, white margin, black corner
    square at (-cols/2, -rows/2)."""
    i = np.floor(x / board.square + board.cols / 2)
    j = np.floor(y / board.square + board.rows / 2)
    inside = (i >= 0) & (i < board.cols) & (j >= 0) & (j < board.rows)
    black = inside & ((i + j) % 2 == 0)
    return np.where(black, _BLACK, _WHITE)


def _cast(
    origin: np.ndarray,
    dirs: np.ndarray,
    board: Checkerboard,
    board_to_laser: Rigid | None,
    wall_m: float,
    ground_m: float,
    walls: tuple[float, ...] = (-1.0,),
) -> tuple[np.ndarray, np.ndarray]:
    """Rays (laser frame, (N,3) unit ``dirs`` from ``origin``): hit distance (m, inf for
    none) and grey level of the nearest of board (None: none), walls (laser y = side *
    wall_m for each side of ``walls``) and ground (laser x = -ground_m)."""
    n = len(dirs)
    dist = np.full(n, np.inf)
    grey = np.full(n, _SKY)
    planes = [(1, side * wall_m, _WALL) for side in walls] + [(0, -ground_m, _GROUND)]
    with np.errstate(divide="ignore", invalid="ignore"):
        for axis, level, colour in planes:
            s = (level - origin[axis]) / dirs[:, axis]
            hit = np.isfinite(s) & (s > 0) & (s < dist)
            dist = np.where(hit, s, dist)
            grey = np.where(hit, colour, grey)
        if board_to_laser is None:
            return dist, grey
        w = board_to_laser.rotation[:, 2]
        C = board_to_laser.translation
        s = ((C - origin) @ w) / (dirs @ w)
    local = origin + np.nan_to_num(s, posinf=0.0, neginf=0.0)[:, None] * dirs - C
    local = local @ board_to_laser.rotation
    hit = (
        np.isfinite(s)
        & (s > 0)
        & (s < dist)
        & (np.abs(local[:, 0]) <= board.width / 2)
        & (np.abs(local[:, 1]) <= board.height / 2)
    )
    dist = np.where(hit, s, dist)
    grey = np.where(hit, _checker(board, local[:, 0], local[:, 1]), grey)
    return dist, grey


def pixel_rays(lens: CameraModel, supersample: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Unit rays (camera frame, (H*k*W*k, 3)) of ``supersample`` x ``supersample`` samples
    per pixel, row-major, and whether each is inside the lens's field of view."""
    W, H, k = lens.width, lens.height, supersample
    u = (np.arange(W * k) + 0.5) / k - 0.5
    v = (np.arange(H * k) + 0.5) / k - 0.5
    uu, vv = np.meshgrid(u, v)
    rays = lens.unproject(np.column_stack([uu.ravel(), vv.ravel()]))
    _, valid = lens.project(rays)
    return rays, valid & np.isfinite(rays).all(axis=1)


def render_frame(
    lens: CameraModel,
    camera_to_laser: Rigid,
    board: Checkerboard,
    board_to_laser: Rigid | None,
    *,
    wall_m: float = 6.0,
    ground_m: float = 2.2,
    supersample: int = 2,
    rays: tuple[np.ndarray, np.ndarray] | None = None,
    walls: tuple[float, ...] = (-1.0,),
) -> np.ndarray:
    """(H,W) float32 grey image of the scene through ``lens`` (black outside its circle;
    ``board_to_laser`` None: no board); ``rays``: :func:`pixel_rays` of the same
    ``supersample``, when already computed; ``walls``: as :func:`_cast`'s."""
    W, H, k = lens.width, lens.height, supersample
    dirs, valid = rays if rays is not None else pixel_rays(lens, k)
    dirs = dirs @ camera_to_laser.rotation.T
    _, grey = _cast(
        camera_to_laser.translation, dirs, board, board_to_laser, wall_m, ground_m, walls
    )
    img = np.where(valid, grey, 0.0).reshape(H * k, W * k)
    if k > 1:
        img = img.reshape(H, k, W, k).mean(axis=(1, 3))
    return img.astype(np.float32)


def simulate_scan(
    rig: Rig,
    board: Checkerboard,
    board_to_laser: Rigid,
    rng: np.random.Generator,
    *,
    wall_m: float = 6.0,
    ground_m: float = 2.2,
    walls: tuple[float, ...] = (-1.0,),
) -> np.ndarray:
    """(n_steps,) float32 ranges (m; +inf no return) with the rig's range noise."""
    a = rig.angles
    dirs = np.column_stack([np.cos(a), np.sin(a), np.zeros_like(a)])
    dist, _ = _cast(np.zeros(3), dirs, board, board_to_laser, wall_m, ground_m, walls)
    dist = dist + rng.normal(0.0, rig.range_noise, dist.shape)
    dist = np.where((dist > rig.min_range) & (dist < rig.max_range), dist, np.inf)
    return dist.astype(np.float32)


def board_at(boards: list[Rigid], t: float, hold_s: float, move_s: float) -> Rigid:
    """The board at ``t`` s: still for ``hold_s`` in pose i, then moving ``move_s`` to i+1
    (linear translation, rotation along the geodesic)."""
    period = hold_s + move_s
    i = min(int(t // period), len(boards) - 1)
    f = (t - i * period - hold_s) / move_s
    if i == len(boards) - 1 or f <= 0:
        return boards[i]
    f = min(f, 1.0)
    a, b = boards[i], boards[i + 1]
    Rf = matrix_from_rotvec(f * rotvec_from_matrix(b.rotation @ a.rotation.T))
    return Rigid(Rf @ a.rotation, (1 - f) * a.translation + f * b.translation)


def open_sim_log(
    directory: Path, prefix: str, rig: Rig, calib: Calibration, *, timing: bool = False
) -> LogWriter:
    """A log writer with the recorder's laser, clock and camera topics (one camera per
    entry of ``calib``; ``timing``: their ``/acq/timing/<name>`` too), the scanner's
    geometry and ``calib`` in its metadata."""
    geometry = {
        "angle_min": rig.angle_min,
        "angle_increment": rig.angle_increment,
        "n_steps": rig.n_steps,
        "time_increment": rig.time_increment,
        "scan_period": rig.scan_period,
        "min_range": rig.min_range,
        "max_range": rig.max_range,
    }
    metadata = {
        "device.laser": {"driver": "sim", "geometry": json.dumps(geometry)},
        **{f"device.{name}": {"driver": "sim"} for name in calib.cameras},
        "calibration": {"yaml": calibfile.dump(calib)},
    }
    writer = LogWriter(directory, prefix=prefix, metadata=metadata, time_base=SIM_TIME_BASE)
    writer.add_channel("/laser/scan", schemas.SCHEMAS["foxglove.LaserScan"])
    writer.add_channel("/laser/raw", schemas.SCHEMAS["acq.RawTelegram"])
    for name in calib.cameras:
        writer.add_channel(f"/{name}/image/compressed", schemas.SCHEMAS["foxglove.CompressedImage"])
        if timing:
            writer.add_channel(f"/acq/timing/{name}", schemas.SCHEMAS["acq.Timing"])
    writer.add_channel("/acq/clock", schemas.SCHEMAS["acq.Clock"])
    return writer


def scan_events(rig: Rig, ranges: np.ndarray, k: int, stamp: int) -> list[tuple[int, str, bytes]]:
    """The /laser/scan and /laser/raw messages of scan ``k`` with point 0 at ``stamp`` ns."""
    scan = Scan(
        ranges=ranges,
        intensities=np.zeros(0, np.float32),
        angle_min=rig.angle_min,
        angle_increment=rig.angle_increment,
        time_increment=rig.time_increment,
        scan_period=rig.scan_period,
        recv_ns=stamp + 30_000_000,
        start_ns=stamp,
        sequence=k,
    )
    raw = schemas.raw_telegram(device="laser", data=b"", recv_ns=stamp, stamp_ns=stamp)
    return [
        (stamp, "/laser/scan", schemas.laser_scan(scan, "laser", SIM_TIME_BASE.to_log(stamp))),
        (stamp, "/laser/raw", raw),
    ]


def write_events(
    writer: LogWriter, events: list[tuple[int, str, bytes]], start_ns: int, duration_s: float
) -> None:
    """Write ``events`` (ns, topic, payload) in time order with 1 Hz /acq/clock pairs, and
    close the writer."""
    for k in range(int(duration_s) + 1):
        stamp = start_ns + k * 10**9
        clock = schemas.clock(realtime_ns=SIM_TIME_BASE.to_log(stamp), monotonic_ns=stamp)
        events.append((stamp, "/acq/clock", clock))
    events.sort(key=lambda e: e[0])
    try:
        for stamp, topic, payload in events:
            writer.write(topic, payload, stamp, stamp)
    finally:
        writer.close()


@dataclass(frozen=True)
class _Grid:
    """A camera's sampling rays in the laser frame, (Hg, Wg, 3), ``per_px`` samples per
    pixel along each axis, whether each is in the field of view, and the grey levels of
    the scene without the board there."""

    dirs: np.ndarray
    valid: np.ndarray
    per_px: float
    background: np.ndarray

    @classmethod
    def of(
        cls,
        rays: tuple[np.ndarray, np.ndarray],
        shape: tuple[int, int],
        per_px: float,
        camera_to_laser: Rigid,
        board: Checkerboard,
        walls: tuple[float, ...],
    ) -> _Grid:
        dirs = (rays[0] @ camera_to_laser.rotation.T).reshape(*shape, 3)
        valid = rays[1].reshape(shape)
        _, grey = _cast(camera_to_laser.translation, dirs.reshape(-1, 3), board, None, 6.0, 2.2,
                        walls)  # fmt: skip
        return cls(dirs, valid, per_px, np.where(valid, grey.reshape(shape), 0.0))

    def grey(
        self,
        lens: CameraModel,
        camera_to_laser: Rigid,
        board: Checkerboard,
        pose: Rigid,
        walls: tuple[float, ...],
    ) -> np.ndarray:
        """(Hg, Wg) grey levels with the board at ``pose``: only the samples around its
        image are cast, the rest is the background."""
        xs = np.linspace(-board.width / 2, board.width / 2, 9)
        ys = np.linspace(-board.height / 2, board.height / 2, 9)
        X, Y = np.meshgrid(xs, ys)
        outline = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
        uv, seen = lens.project((camera_to_laser.inverse() @ pose).apply(outline))
        Hg, Wg = self.valid.shape
        if not seen.any():
            return self.background
        if seen.all():  # the board's straight edges bend by less than the margin between
            lo = np.floor((uv.min(axis=0) - 8.0) * self.per_px).astype(int)
            hi = np.ceil((uv.max(axis=0) + 8.0) * self.per_px).astype(int)
            u0, v0 = max(lo[0], 0), max(lo[1], 0)
            u1, v1 = min(hi[0], Wg), min(hi[1], Hg)
        else:  # partly out of view: cast everything
            u0, v0, u1, v1 = 0, 0, Wg, Hg
        out = self.background.copy()
        if u1 <= u0 or v1 <= v0:
            return out
        sub = self.dirs[v0:v1, u0:u1].reshape(-1, 3)
        _, g = _cast(camera_to_laser.translation, sub, board, pose, 6.0, 2.2, walls)
        out[v0:v1, u0:u1] = np.where(self.valid[v0:v1, u0:u1], g.reshape(v1 - v0, u1 - u0), 0.0)
        return out


def _frames(
    cam: RigCamera,
    k_cam: int,
    rig: Rig,
    boards: list[Rigid],
    board: Checkerboard,
    walls: tuple[float, ...],
    noise: list[np.ndarray],
    timing: bool,
    *,
    duration: float,
    hold_s: float,
    move_s: float,
    blur_px: float,
    jpeg_quality: int,
    start_ns: int,
) -> list[tuple[int, str, bytes]]:
    """The frame events (and with ``timing`` the timing records) of rig camera ``cam``
    (the ``k_cam``-th), at its own phase of the frame period over ``duration`` s."""
    lens, truth, name = cam.lens, cam.camera_to_laser, cam.name
    W, H = lens.width, lens.height
    phase = (k_cam * 0.37 % 1.0) / rig.fps  # unsynchronised cameras
    fine = _Grid.of(pixel_rays(lens, 2), (2 * H, 2 * W), 2.0, truth, board, walls)
    # moving frames: every other pixel, scaled up (motion blurs them anyway)
    rays1 = pixel_rays(lens, 1)
    half = [r.reshape(H, W, -1)[::2, ::2] for r in rays1]
    hh, hw = half[0].shape[:2]
    coarse = _Grid.of((half[0].reshape(-1, 3), half[1].reshape(-1)), (hh, hw), 0.5, truth,
                      board, walls)  # fmt: skip
    still = [
        fine.grey(lens, truth, board, b, walls).reshape(H, 2, W, 2).mean(axis=(1, 3))
        for b in boards
    ]
    n_poses = len(boards)
    events: list[tuple[int, str, bytes]] = []
    topic = f"/{name}/image/compressed"
    for k in range(int((duration - phase) * rig.fps) + 1):
        t = phase + k / rig.fps
        B = board_at(boards, t, hold_s, move_s)
        i = min(int(t // (hold_s + move_s)), n_poses - 1)
        if B is boards[i]:
            img = still[i].astype(np.float32)
        else:
            g = coarse.grey(lens, truth, board, B, walls).astype(np.float32)
            img = cv2.resize(g, (W, H), interpolation=cv2.INTER_LINEAR)
        img = cv2.GaussianBlur(img, (0, 0), blur_px) + noise[k % len(noise)]
        grey = np.clip(np.rint(img), 0, 255).astype(np.uint8)
        ok, buf = cv2.imencode(".jpg", grey, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
        if not ok:
            raise RuntimeError("JPEG encoding failed")
        stamp = start_ns + round(t * 1e9)
        if timing:
            recv = stamp + round((cam.exposure / 2 + cam.latency_s) * 1e9)
            record = schemas.timing(recv_ns=recv, stamp_ns=stamp, sequence=k, received=k + 1)
            events.append((stamp, f"/acq/timing/{name}", record))
        else:
            recv = stamp + 2_000_000
        frame = Frame(recv, stamp, k, lens.width, lens.height, jpeg=buf.tobytes())
        events.append(
            (stamp, topic, schemas.compressed_image(frame, name, SIM_TIME_BASE.to_log(stamp)))
        )
    return events


def write_board_log(
    directory: Path,
    n_poses: int = 12,
    seed: int = 0,
    *,
    hold_s: float = 1.5,
    move_s: float = 0.4,
    rig: Rig | None = None,
    board: Checkerboard = BOARD,
    distance: tuple[float, float] = (1.0, 2.5),
    blur_px: float = 0.6,
    pixel_noise: float = 1.5,
    jpeg_quality: int = 92,
    start_ns: int = 1_000_000_000_000,
) -> BoardLog:
    """Write the recording (see the module docstring) into ``directory``: ``n_poses``
    poses for each camera of ``rig`` (default ``default_rig()``); the truth."""
    rig = rig or default_rig()
    rng = np.random.default_rng(seed + 1)
    boards: list[Rigid] = []
    placed_for: list[str] = []
    for j, cam in enumerate(rig.cameras):
        data = simulate(n_poses, seed + 101 * j, rig=rig.only(cam.name), board=board,
                        true_planes=True, range_noise=0.0, distance=distance)  # fmt: skip
        boards += data.boards
        placed_for += [cam.name] * n_poses
    several = len(rig.cameras) > 1
    walls = (-1.0, 1.0) if several else (-1.0,)
    calib = Calibration(cameras={c.name: CameraCalib(c.lens) for c in rig.cameras})
    total = len(boards)
    duration = total * (hold_s + move_s) - move_s
    writer = open_sim_log(directory, "board", rig, calib, timing=several)
    noises = [
        [rng.normal(0.0, pixel_noise, (c.lens.height, c.lens.width)).astype(np.float32)
         for _ in range(4)]
        for c in rig.cameras
    ]  # fmt: skip
    events: list[tuple[int, str, bytes]] = []
    for j, cam in enumerate(rig.cameras):
        events += _frames(
            cam, j, rig, boards, board, walls, noises[j], several, duration=duration,
            hold_s=hold_s, move_s=move_s, blur_px=blur_px, jpeg_quality=jpeg_quality,
            start_ns=start_ns,
        )  # fmt: skip
    n_scans = int(duration / rig.scan_period) + 1
    for k in range(n_scans):
        t = k * rig.scan_period
        B = board_at(boards, t + 0.5 * rig.scan_period * 0.75, hold_s, move_s)
        ranges = simulate_scan(rig, board, B, rng, walls=walls)
        events += scan_events(rig, ranges, k, start_ns + round(t * 1e9))
    write_events(writer, events, start_ns, duration)
    period_ns = round((hold_s + move_s) * 1e9)
    holds = [
        (start_ns + i * period_ns, start_ns + i * period_ns + round(hold_s * 1e9))
        for i in range(total)
    ]
    spec = f"{board.cols - 1}x{board.rows - 1}x{board.square:g}"
    truths = {c.name: c.camera_to_laser for c in rig.cameras}
    return BoardLog(writer.files, rig.camera_to_laser, boards, holds, board, spec, calib,
                    start_ns, truths, tuple(placed_for))  # fmt: skip
