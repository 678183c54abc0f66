"""A recorded drive -> coloured 3D points: every laser point placed at its own time and
coloured by the camera frame nearest to it in time.

Reading (:func:`read_log`): ``/<laser>/scan`` (``foxglove.LaserScan``: the timestamp is
the host time of point 0), the scanner's ``device.<laser>`` metadata (``geometry``:
``time_increment`` s per point), ``/<camera>/image/compressed`` (stamped at the middle
of the exposure), the ``/acq/timing/*`` records (device ticks, frame sequence numbers),
the ``/acq/clock`` (UTC, monotonic) pairs and the ``calibration`` metadata.

Placement (:func:`colorize`): point ``i`` of a scan was measured at
``scan start + i * time_increment``; ``pose_at`` gives the vehicle's pose (vehicle ->
world) at those host times, and the calibration's ``laser_to_vehicle`` puts the laser on
the vehicle. Colour: each point goes back into the nearest frame's instant (world ->
vehicle at the frame's time -> laser -> camera, paper eq. 2 inverted) and takes the
bilinear colour of its pixel; points no frame sees (behind the camera, outside its field
of view or the image, or too far in time from any frame) are kept and flagged.
Occlusion is not checked: a point hidden from the camera by something nearer takes that
thing's colour.

Times are host ``CLOCK_MONOTONIC`` ns (int64) unless a name ends in ``_s``; positions
are metres in the frame ``pose_at`` maps to (``world``); colours RGB uint8.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from acq import calibfile, loginfo, projection, sync, views
from acq.calibfile import Calibration
from acq.transforms import Rigid
from acq.vehicle_log import VehicleLog, VehicleReader

__all__ = [
    "Cloud",
    "DriveLog",
    "PlyStream",
    "PoseFn",
    "calibration_of",
    "colorize",
    "preview_image",
    "preview_png",
    "read_log",
    "utc_seconds",
    "write_ply",
]

PoseFn = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
"""Vehicle pose at host times: (N,) int64 ns -> rotations (N,3,3), translations (N,3) m,
``P_world = R @ P_vehicle + t``."""

UNCOLOURED_RGB = (128, 128, 128)  # what the preview draws for a point no frame sees


# --- reading ---------------------------------------------------------------------------


@dataclass(frozen=True)
class DriveLog:
    """What colouring needs from one log or the split files of one session.

    Scans: ``scan_ns`` (S,) host ns of point 0; ``ranges`` and ``intensities`` (S, N)
    float32 (REP-117 ranges, m; intensities zero where the device sends none);
    ``angle_min``, ``angle_increment`` rad and ``time_increment`` s per point;
    ``scan_ticks`` (S,) the device clock tick of each scan (-1 where unknown). Frames:
    ``frame_ns`` (F,) host ns of the middle of exposure, ``frame_seq`` (F,) the
    driver's sequence numbers (-1 where unknown; they restart on a reconnect), ``jpegs``
    the bytes as the camera sent them. ``clock`` (K,2) int64 pairs (monotonic ns,
    realtime ns). ``metadata`` by name (the last record of each name). ``vehicle``: the
    odometry and GNSS fixes (:class:`acq.vehicle_log.VehicleLog`) when read with them.
    """

    files: tuple[Path, ...]
    laser: str
    camera: str
    scan_ns: np.ndarray
    ranges: np.ndarray
    intensities: np.ndarray
    angle_min: float
    angle_increment: float
    time_increment: float
    scan_ticks: np.ndarray
    frame_ns: np.ndarray
    frame_seq: np.ndarray
    jpegs: list[bytes]
    clock: np.ndarray
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)  # what was missing and assumed
    scan_recv_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    frame_recv_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    vehicle: VehicleLog | None = None

    @property
    def n_scans(self) -> int:
        return int(self.scan_ns.size)

    @property
    def n_frames(self) -> int:
        return int(self.frame_ns.size)

    def between(self, lo_ns: int, hi_ns: int) -> DriveLog:
        """The scans and frames stamped in [lo_ns, hi_ns) (recorded stamps)."""
        s = (self.scan_ns >= lo_ns) & (self.scan_ns < hi_ns)
        f = np.flatnonzero((self.frame_ns >= lo_ns) & (self.frame_ns < hi_ns))

        def part(a: np.ndarray, sel: np.ndarray) -> np.ndarray:
            return a[sel] if a.size else a

        return replace(
            self,
            scan_ns=self.scan_ns[s],
            ranges=self.ranges[s],
            intensities=self.intensities[s],
            scan_ticks=part(self.scan_ticks, s),
            scan_recv_ns=part(self.scan_recv_ns, s),
            frame_ns=self.frame_ns[f],
            frame_seq=part(self.frame_seq, f),
            frame_recv_ns=part(self.frame_recv_ns, f),
            jpegs=[self.jpegs[int(i)] for i in f],
        )


def _pick(found: Iterable[str], name: str | None, what: str, topic: str) -> str:
    """The device ``name``, or the only one ``found``; ValueError naming the choices."""
    names = sorted(found)
    if name is not None:
        if name not in names:
            raise ValueError(f"no {what} {name!r} in the log (has {', '.join(names) or 'none'})")
        return name
    if not names:
        raise ValueError(f"no {what} in the log (no /<name>{topic} messages)")
    if len(names) > 1:
        raise ValueError(f"the log has several {what}s ({', '.join(names)}); name one")
    return names[0]


@dataclass(frozen=True)
class _ScanMsg:
    stamp_ns: int
    ranges: np.ndarray
    intensities: np.ndarray
    start_angle: float
    end_angle: float


def _stamp(msg: Any) -> int:
    return int(msg.timestamp.seconds) * 10**9 + int(msg.timestamp.nanos)


def _stamp_of(message: Any) -> int:
    """An MCAP message's publish time: the recorder puts the stamp there."""
    return int(message.publish_time)


def read_log(
    paths: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    *,
    laser: str | None = None,
    camera: str | None = None,
    start_ns: int | None = None,
    end_ns: int | None = None,
    jpegs: bool = True,
    vehicle: bool = False,
) -> DriveLog:
    """Scans, frames, clock pairs and metadata of a log (or of a session's files, in the
    order given). ``laser``/``camera`` name the devices where the log has several.
    ``start_ns``/``end_ns``: only messages received (MCAP log time) in that span, and
    only the chunks of a closed file that hold some (a long log's part reads in the
    time of that part): the clock pairs, and with ``vehicle`` the odometry and GNSS
    fixes, whatever their time in those chunks; metadata whatever their time.
    ``jpegs=False`` leaves the images' bytes out (their stamps stay); ``vehicle``: also
    the odometry and GNSS fixes, in the same pass, as
    :func:`acq.vehicle_log.read_vehicle`.

    Files whose writer was killed are read up to their last good record
    (:func:`acq.loginfo.read_messages`); undecodable messages are skipped (noted).
    Raises :class:`acq.loginfo.LogError` for a file that is not MCAP, ValueError when
    the log has no scans or several lasers/cameras. A log without frames reads with
    ``camera`` "" and no frames.
    """
    from mcap_protobuf.decoder import DecoderFactory

    if isinstance(paths, str | os.PathLike):
        files: tuple[Path, ...] = (Path(paths),)
    else:
        files = tuple(Path(p) for p in paths)
    metadata: dict[str, dict[str, str]] = {}
    scans: dict[str, list[_ScanMsg]] = {}
    frames: dict[str, list[tuple[int, bytes]]] = {}
    timing: dict[str, dict[int, tuple[int, int, int]]] = {}  # stamp -> (tick, seq, recv)
    lo = -(2**63) if start_ns is None else start_ns
    hi = 2**63 - 1 if end_ns is None else end_ns
    clock: list[tuple[int, int]] = []
    bad = 0
    vehicle_reader = VehicleReader() if vehicle else None
    vehicle_topics = VehicleReader.TOPICS if vehicle else ()
    for path in files:
        metadata.update(loginfo.read_metadata(path))
        factory = DecoderFactory()
        decoders: dict[int, Any] = {}
        span = None if start_ns is None and end_ns is None else (lo, hi)
        for schema, channel, message in loginfo.read_messages(path, span):
            topic = channel.topic
            if topic in vehicle_topics and vehicle_reader is not None:
                try:
                    if channel.id not in decoders:
                        decoders[channel.id] = factory.decoder_for(channel.message_encoding, schema)
                    vehicle_reader.add(topic, decoders[channel.id](message.data))
                except Exception:  # a garbled payload or schema: that message is lost
                    vehicle_reader.bad += 1
                continue
            wanted = topic.endswith(("/scan", "/image/compressed")) or topic.startswith(
                ("/acq/clock", "/acq/timing/")
            )
            if not wanted or (
                not lo <= message.log_time <= hi and not topic.startswith("/acq/clock")
            ):
                continue
            if not jpegs and topic.endswith("/image/compressed"):
                name = topic[1:].removesuffix("/image/compressed")
                frames.setdefault(name, []).append((_stamp_of(message), b""))
                continue
            try:
                if channel.id not in decoders:
                    decoders[channel.id] = factory.decoder_for(channel.message_encoding, schema)
                msg = decoders[channel.id](message.data)
                if topic.endswith("/scan"):
                    scans.setdefault(topic[1:].removesuffix("/scan"), []).append(
                        _ScanMsg(
                            _stamp(msg),
                            np.asarray(msg.ranges, dtype=np.float32),
                            np.asarray(msg.intensities, dtype=np.float32),
                            float(msg.start_angle),
                            float(msg.end_angle),
                        )
                    )
                elif topic.endswith("/image/compressed"):
                    name = topic[1:].removesuffix("/image/compressed")
                    frames.setdefault(name, []).append((_stamp(msg), bytes(msg.data)))
                elif topic == "/acq/clock":
                    clock.append((int(msg.monotonic_ns), int(msg.realtime_ns)))
                elif topic.startswith("/acq/timing/"):
                    ticks = list(msg.device_ticks)
                    timing.setdefault(topic.removeprefix("/acq/timing/"), {})[int(msg.stamp_ns)] = (
                        int(ticks[0]) if ticks else -1,
                        int(msg.sequence),
                        int(msg.recv_ns),
                    )
            except Exception:  # a garbled payload or schema: that message is lost
                bad += 1
    laser = _pick(scans, laser, "laser scanner", "/scan")
    camera = "" if camera is None and not frames else _pick(frames, camera, "camera", "/image")
    notes = [f"{bad} undecodable messages skipped"] if bad else []
    log = _assemble(
        files,
        laser,
        camera,
        scans[laser],
        frames.get(camera, []),
        timing,
        clock,
        metadata,
        notes,
    )
    if vehicle_reader is not None:
        log = replace(log, vehicle=vehicle_reader.result(files))
    return log


def _assemble(
    files: tuple[Path, ...],
    laser: str,
    camera: str,
    scans: list[_ScanMsg],
    frames: list[tuple[int, bytes]],
    timing: dict[str, dict[int, tuple[int, int, int]]],
    clock: list[tuple[int, int]],
    metadata: dict[str, dict[str, str]],
    notes: list[str],
) -> DriveLog:
    scans.sort(key=lambda m: m.stamp_ns)
    n = max(m.ranges.size for m in scans)
    first = next(m for m in scans if m.ranges.size == n)
    angle_min = first.start_angle
    inc = (first.end_angle - angle_min) / (n - 1) if n > 1 else 0.0
    ranges = np.full((len(scans), n), np.nan, dtype=np.float32)
    intens = np.zeros((len(scans), n), dtype=np.float32)
    for k, m in enumerate(scans):
        if m.ranges.size != n:  # a cropped scan after a reconfiguration: not placed
            notes.append(f"scan {k} has {m.ranges.size} points, not {n}: skipped")
            continue
        ranges[k] = m.ranges
        if m.intensities.size == n:
            intens[k] = m.intensities
    scan_ns = np.array([m.stamp_ns for m in scans], dtype=np.int64)
    geometry = json.loads(metadata.get(f"device.{laser}", {}).get("geometry", "null") or "null")
    if geometry and geometry.get("time_increment") is not None:
        time_increment = float(geometry["time_increment"])
    else:
        # a rotating mirror: one step of the turn per angle increment
        period = float(np.median(np.diff(scan_ns))) * 1e-9 if scan_ns.size > 1 else 0.0
        time_increment = period * abs(inc) / (2 * math.pi)
        notes.append(
            f"no device.{laser} geometry: time_increment {time_increment * 1e6:.2f} us "
            "assumed from the scan rate (a full turn per scan)"
        )
    lt = timing.get(laser, {})
    scan_ticks = np.array([lt.get(int(t), (-1, 0, -1))[0] for t in scan_ns], dtype=np.int64)
    scan_recv = np.array([lt.get(int(t), (-1, 0, -1))[2] for t in scan_ns], dtype=np.int64)
    frames.sort(key=lambda f: f[0])
    frame_ns = np.array([t for t, _ in frames], dtype=np.int64)
    ct = timing.get(camera, {})
    frame_seq = np.array([ct.get(int(t), (0, -1, -1))[1] for t in frame_ns], dtype=np.int64)
    frame_recv = np.array([ct.get(int(t), (0, -1, -1))[2] for t in frame_ns], dtype=np.int64)
    return DriveLog(
        files=files,
        laser=laser,
        camera=camera,
        scan_ns=scan_ns,
        ranges=ranges,
        intensities=intens,
        angle_min=angle_min,
        angle_increment=inc,
        time_increment=time_increment,
        scan_ticks=scan_ticks,
        frame_ns=frame_ns,
        frame_seq=frame_seq,
        jpegs=[j for _, j in frames],
        clock=np.array(clock, dtype=np.int64).reshape(-1, 2),
        metadata=metadata,
        notes=notes,
        scan_recv_ns=scan_recv,
        frame_recv_ns=frame_recv,
    )


def calibration_of(log: DriveLog) -> Calibration:
    """The calibration the recorder stored in the log's ``calibration`` metadata."""
    text = log.metadata.get("calibration", {}).get("yaml")
    if not text:
        raise ValueError(f"{log.files[0]}: no calibration in the log's metadata; give one")
    return calibfile.parse(yaml.safe_load(text), f"{log.files[0]}: calibration metadata")


# --- colouring -------------------------------------------------------------------------


@dataclass(frozen=True)
class Cloud:
    """Coloured points, one per laser return, in scan order.

    Per point: ``xyz`` (P,3) float64 m in the world frame; ``rgb`` (P,3) uint8 (zero
    where not coloured); ``coloured`` (P,) bool; ``time_ns`` (P,) int64 host monotonic
    ns of the measurement; ``scan`` (P,) uint32 index of its scan in the log; ``step``
    (P,) uint32 its index within the scan; ``intensity`` (P,) float32 device units;
    ``dt_s`` (P,) float32 its time minus its frame's (NaN where not coloured).
    Per scan: ``scan_origin`` (S,3) the laser's position in the world at point 0.
    ``view_axis`` (3,) the camera's mean optical axis in the world (unit). ``clock``
    (K,2) the log's (monotonic ns, realtime ns) pairs. ``frames`` frames in the log,
    ``frames_used`` decoded and used, ``frames_failed`` not decodable.
    """

    xyz: np.ndarray
    rgb: np.ndarray
    coloured: np.ndarray
    time_ns: np.ndarray
    scan: np.ndarray
    step: np.ndarray
    intensity: np.ndarray
    dt_s: np.ndarray
    scan_origin: np.ndarray
    view_axis: np.ndarray
    clock: np.ndarray
    frames: int = 0
    frames_used: int = 0
    frames_failed: int = 0

    @property
    def size(self) -> int:
        return int(self.time_ns.size)

    @property
    def coloured_share(self) -> float:
        return float(self.coloured.mean()) if self.size else 0.0


def _transform(R: np.ndarray, t: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Per-point rigid transforms: R (N,3,3), t (N,3), P (N,3) -> R @ P + t."""
    return np.einsum("nij,nj->ni", R, P) + t


def _inverse_transform(R: np.ndarray, t: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Per-point inverse: R.T @ (P - t)."""
    return np.einsum("nji,nj->ni", R, P - t)


def colorize(
    log: DriveLog,
    calib: Calibration,
    pose_at: PoseFn,
    *,
    camera: str | None = None,
    max_dt_s: float = 0.1,
    bilinear: bool = True,
    threads: int = 2,
) -> Cloud:
    """Every laser return of ``log`` placed in the world and coloured (see module doc).

    ``calib`` gives the camera (``camera``, default the log's camera) with its
    ``camera_to_laser`` and ``time_offset_s`` (camera time minus laser time), and
    ``laser_to_vehicle`` (identity when absent). ``pose_at`` maps host ns to vehicle
    poses. A point is coloured by its nearest frame in time when that frame is within
    ``max_dt_s`` s and sees it. JPEGs are decoded once each, on ``threads`` threads.
    """
    cam = calib.camera(camera if camera is not None else (log.camera or None))
    l2v = calib.laser_to_vehicle if calib.laser_to_vehicle is not None else Rigid.identity()
    # the points and their times
    valid = np.isfinite(log.ranges)
    scan_idx, step = np.nonzero(valid)
    r = log.ranges[scan_idx, step].astype(np.float64)
    a = log.angle_min + log.angle_increment * step
    P_laser = np.stack([r * np.cos(a), r * np.sin(a), np.zeros_like(r)], axis=1)
    offsets = np.rint(step * (log.time_increment * 1e9)).astype(np.int64)
    time_ns = log.scan_ns[scan_idx] + offsets
    # placed at their own time
    Rv, tv = pose_at(time_ns)
    P_vehicle = l2v.apply(P_laser)
    xyz = _transform(Rv, tv, P_vehicle)
    Rs, ts = pose_at(log.scan_ns)
    scan_origin = _transform(Rs, ts, np.broadcast_to(l2v.translation, ts.shape))
    cam_axis_vehicle = (l2v @ cam.camera_to_laser).rotation[:, 2]
    view = np.einsum("nij,j->ni", Rs, cam_axis_vehicle).mean(axis=0)
    view_axis = view / max(float(np.linalg.norm(view)), 1e-12)

    # the nearest frame of each point, in the laser's time
    n = time_ns.size
    rgb = np.zeros((n, 3), dtype=np.uint8)
    coloured = np.zeros(n, dtype=bool)
    dt_s = np.full(n, np.nan, dtype=np.float32)
    frames_used = frames_failed = 0
    if log.n_frames:
        frame_ns = log.frame_ns - round(cam.time_offset_s * 1e9)
        # by time alone: the driver's sequence numbers restart when the camera reconnects
        pairing = sync.pair_frames(time_ns, frame_ns)
        near = pairing.nearest
        candidate = np.flatnonzero((near >= 0) & (np.abs(pairing.dt_s) <= max_dt_s))
        order = candidate[np.argsort(near[candidate], kind="stable")]
        used, first, counts = np.unique(near[order], return_index=True, return_counts=True)
        # every candidate point into the laser frame at its frame's instant
        Rf, tf = pose_at(frame_ns[used])
        k = np.repeat(np.arange(used.size), counts)
        P_lf = l2v.inverse().apply(_inverse_transform(Rf[k], tf[k], xyz[order]))
        bgr = np.zeros((order.size, 3), dtype=np.uint8)
        seen = np.zeros(order.size, dtype=bool)
        images = views.decoded_frames(log.jpegs, used, threads)
        for lo, count, image in zip(first, counts, images, strict=True):
            if image is None:
                frames_failed += 1
                continue
            frames_used += 1
            hi = lo + count
            bgr[lo:hi], seen[lo:hi] = projection.colorize(
                P_lf[lo:hi], cam.model, cam.camera_to_laser, image, bilinear=bilinear
            )
        hit = order[seen]
        rgb[hit] = bgr[seen][:, ::-1]
        coloured[hit] = True
        dt_s[hit] = pairing.dt_s[hit]
    intensity = log.intensities[scan_idx, step]
    return Cloud(
        xyz=xyz,
        rgb=rgb,
        coloured=coloured,
        time_ns=time_ns,
        scan=scan_idx.astype(np.uint32),
        step=step.astype(np.uint32),
        intensity=intensity.astype(np.float32),
        dt_s=dt_s,
        scan_origin=scan_origin,
        view_axis=view_axis,
        clock=log.clock,
        frames=log.n_frames,
        frames_used=frames_used,
        frames_failed=frames_failed,
    )


# --- writing ---------------------------------------------------------------------------


def utc_seconds(time_ns: np.ndarray, clock: np.ndarray) -> np.ndarray:
    """Host monotonic ns -> UTC seconds (float64) with the log's (monotonic, realtime)
    pairs, the offset interpolated between pairs (held at the ends); NaN without pairs."""
    t = np.asarray(time_ns, dtype=np.int64)
    if clock.size == 0:
        return np.full(t.shape, np.nan)
    mono = clock[:, 0]
    offset = clock[:, 1] - mono
    base = int(offset[0])
    order = np.argsort(mono, kind="stable")
    rel = np.interp(t.astype(np.float64), mono[order].astype(np.float64), (offset - base)[order])
    # whole seconds and the rest apart, so float64 keeps the nanoseconds' microseconds
    total = t + base + np.rint(rel).astype(np.int64)
    return (total // 10**9).astype(np.float64) + (total % 10**9).astype(np.float64) * 1e-9


PLY_DTYPE = np.dtype(
    [
        ("x", "<f8"),
        ("y", "<f8"),
        ("z", "<f8"),
        ("red", "u1"),
        ("green", "u1"),
        ("blue", "u1"),
        ("time", "<f8"),
        ("scan", "<u4"),
        ("intensity", "<f4"),
        ("coloured", "u1"),
    ]
)


_PLY_TYPES = {"<f8": "double", "|u1": "uchar", "<u4": "uint", "<f4": "float"}


class PlyStream:
    """A binary little-endian PLY (see :func:`write_ply`) written part by part to
    ``path``.tmp, renamed on :meth:`close` (:meth:`abort` removes it). Its header, with
    the counts known only at the end, is written last into the room kept for it (the
    rest of the room a comment of spaces)."""

    def __init__(self, path: str | os.PathLike[str], comments: Sequence[str] = ()) -> None:
        self.path = Path(path)
        self._tmp = self.path.with_name(self.path.name + ".tmp")
        self._comments = list(comments)
        self.points = self.coloured = 0
        self._room = len(self._header(10**15, 10**15))
        self._file = open(self._tmp, "wb")
        self._file.seek(self._room)

    def _header(self, points: int, coloured: int, pad: int = 0) -> bytes:
        lines = [
            "ply",
            "format binary_little_endian 1.0",
            "comment acq coloured cloud: x y z metres in the world frame; time UTC seconds",
            f"comment {coloured} of {points} points coloured",
            *(f"comment {c}" for c in self._comments),
            "comment " + " " * pad,  # what is left of the room kept for the header
            f"element vertex {points}",
            *(f"property {_PLY_TYPES[PLY_DTYPE[k].str]} {k}" for k in PLY_DTYPE.names or ()),
            "end_header",
        ]
        return ("\n".join(lines) + "\n").encode()

    def write(
        self, xyz: np.ndarray, rgb: np.ndarray, utc_s: np.ndarray, intensity: np.ndarray,
        scan: np.ndarray, coloured: np.ndarray,
    ) -> None:  # fmt: skip
        """Append points: ``xyz`` (N,3) m, ``rgb`` (N,3) uint8, ``utc_s`` (N,) UTC
        seconds, ``intensity``, ``scan`` index, ``coloured`` flag."""
        v = np.empty(utc_s.size, dtype=PLY_DTYPE)
        v["x"], v["y"], v["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        v["red"], v["green"], v["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
        v["time"] = utc_s
        v["scan"] = scan
        v["intensity"] = intensity
        v["coloured"] = coloured
        v.tofile(self._file)
        self.points += int(v.size)
        self.coloured += int(np.count_nonzero(coloured))

    def close(self) -> int:
        """Write the header and finish the file; its size, bytes."""
        head = self._header(self.points, self.coloured)
        head = self._header(self.points, self.coloured, self._room - len(head))
        self._file.seek(0)
        self._file.write(head)
        self._file.close()
        self._tmp.replace(self.path)
        return self.path.stat().st_size

    def abort(self) -> None:
        """Drop the unfinished file."""
        self._file.close()
        self._tmp.unlink(missing_ok=True)


def write_ply(path: str | os.PathLike[str], cloud: Cloud, comments: Sequence[str] = ()) -> int:
    """Binary little-endian PLY, one ``vertex`` per point: x y z (double, m, world),
    red green blue (uchar), time (double, UTC s), scan (uint), intensity (float),
    coloured (uchar 0/1). Returns the file's size, bytes."""
    out = PlyStream(path, comments)
    try:
        out.write(cloud.xyz, cloud.rgb, utc_seconds(cloud.time_ns, cloud.clock), cloud.intensity,
                  cloud.scan, cloud.coloured)  # fmt: skip
    except BaseException:
        out.abort()
        raise
    return out.close()


# --- the preview -----------------------------------------------------------------------

_BG = (24, 24, 24)  # BGR background
_TEXT = (235, 235, 235)


def _axes(cloud: Cloud) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(along-track, toward the camera's side, origin): horizontal unit vectors in the
    world, from the laser's track and the camera's mean axis."""
    track = cloud.scan_origin
    along = track[-1] - track[0] if len(track) > 1 else np.array([1.0, 0.0, 0.0])
    along = np.array([along[0], along[1], 0.0])
    if np.linalg.norm(along) < 1e-6:
        along = np.array([1.0, 0.0, 0.0])
    along /= np.linalg.norm(along)
    side = np.cross([0.0, 0.0, 1.0], along)  # left of the track
    if float(side @ cloud.view_axis) < 0:
        side = -side
    origin = track[0] if len(track) else np.zeros(3)
    return along, side, origin


def _splat(
    shape: tuple[int, int],
    col: np.ndarray,
    row: np.ndarray,
    depth: np.ndarray,
    colour: np.ndarray,
    width: int,
    heights: np.ndarray,
) -> np.ndarray:
    """(H,W,3) uint8 of points drawn as blocks, the smallest depth winning each pixel.

    Point i covers ``width`` px from its column rightwards and ``heights[i]`` px
    centred on its row; the background shows elsewhere.
    """
    h, w = shape
    img = np.empty((h * w, 3), dtype=np.uint8)
    img[:] = _BG
    nearest_first = np.argsort(depth, kind="stable")
    counts = heights[nearest_first].astype(np.int64) * width
    src = np.repeat(nearest_first, counts)
    k = np.arange(src.size) - np.repeat(np.cumsum(counts) - counts, counts)
    cc = col[src] + k % width
    rr = row[src] + k // width - heights[src] // 2
    inside = (cc >= 0) & (cc < w) & (rr >= 0) & (rr < h)
    flat = (rr * w + cc)[inside]
    src = src[inside]
    pixels, first = np.unique(flat, return_index=True)  # the first is the nearest
    img[pixels] = colour[src[first]]
    return img.reshape(h, w, 3)


def _spacing(v: np.ndarray, scan: np.ndarray, step: np.ndarray) -> np.ndarray:
    """Per point, how far apart in ``v`` its scan's points are around it: the larger
    |difference| to the previous and next step, but at most twice the smaller (an edge
    of a surface is not a spacing); NaN where it has no neighbour."""
    same = (scan[1:] == scan[:-1]) & (step[1:] == step[:-1] + 1)
    d = np.where(same, np.abs(np.diff(v)), np.nan)
    before = np.concatenate([[np.nan], d])
    after = np.concatenate([d, [np.nan]])
    with np.errstate(invalid="ignore"):
        lo = np.fmin(before, after)
        return np.fmin(np.fmax(before, after), 2.0 * lo)


def _heights(gap: np.ndarray, res: float, most: int = 20) -> np.ndarray:
    """Block heights, px: a pixel more than the spacing between a scan's points, 1 to
    ``most``."""
    px = np.ceil(np.nan_to_num(gap, nan=0.0) / res) + 1
    return np.clip(px, 1, most).astype(np.int64)


def _label(img: np.ndarray, text: str, x: int = 10, scale: float = 0.55) -> None:
    cv2.putText(img, text, (x, 23), cv2.FONT_HERSHEY_SIMPLEX, scale, _TEXT, 1, cv2.LINE_AA)


def _band(w: int, text: str, res: float = 0.0, scale: float = 0.55) -> np.ndarray:
    """A 34 px caption strip, with a 10 m scale bar at its right when ``res`` is given."""
    band = np.full((34, w, 3), _BG, dtype=np.uint8)
    _label(band, text, scale=scale)
    bar = round(10.0 / res) if res > 0 else 0
    if bar and bar + 80 < w // 2:
        x1 = w - 60
        cv2.line(band, (x1 - bar, 17), (x1, 17), _TEXT, 2)
        _label(band, "10 m", x1 + 8, 0.5)
    return band


def preview_image(
    cloud: Cloud,
    *,
    metres_per_px: float = 0.03,
    max_width: int = 2400,
    top_half_width_m: float = 12.0,
    title: str = "",
) -> np.ndarray:
    """A picture of the cloud to judge at a glance: (H,W,3) uint8 BGR.

    Top: the side the camera looks at, seen from the street (orthographic; along-track
    distance to the right, height up; the nearest point wins each pixel). Bottom: the
    view from above (along-track to the right, the camera's side up; the highest point
    wins), ``top_half_width_m`` m either side of the track. Uncoloured points are grey.
    The scale is ``metres_per_px``, coarser when the drive would be wider than
    ``max_width`` px. Each point is drawn as a block a pixel wider than the spacing
    between scans and a pixel taller than the spacing between its scan's points (up to
    20 px), so that surfaces close up.
    """
    if cloud.size == 0:
        return _band(640, title or "no points")
    along, side, origin = _axes(cloud)
    rel = cloud.xyz - origin
    u = rel @ along
    lat = rel @ side
    z = cloud.xyz[:, 2]
    colour = np.where(cloud.coloured[:, None], cloud.rgb[:, ::-1], np.array(UNCOLOURED_RGB))
    colour = colour.astype(np.uint8)
    u0, u1 = np.percentile(u, [0.1, 99.9])
    span = max(u1 - u0, 1.0) + 1.0
    res = max(metres_per_px, span / max_width)
    w = math.ceil(span / res)
    step_m = float(np.median(np.linalg.norm(np.diff(cloud.scan_origin, axis=0), axis=1)))
    block = int(np.clip(math.ceil(step_m / res) + 1, 1, 12)) if math.isfinite(step_m) else 1
    col = np.floor((u - u0 + 0.5) / res).astype(np.int64)

    # the facade panel: the camera's side, above the road
    on = lat > 0.5
    ztop = float(np.percentile(z[on], 99.5)) + 0.5 if on.any() else 10.0
    zbot = min(float(np.percentile(z, 0.5)), 0.0) - 0.2
    fh = math.ceil((ztop - zbot) / res)
    row = np.floor((ztop - z) / res).astype(np.int64)
    hz = _heights(_spacing(z, cloud.scan, cloud.step), res)
    facade = _splat((fh, w), col[on], row[on], lat[on], colour[on], block, hz[on])
    # the top panel: highest point wins
    l0, l1 = np.percentile(lat, [0.5, 99.5])
    l0, l1 = max(l0, -top_half_width_m), min(l1, top_half_width_m)
    th = math.ceil((l1 - l0) / res) + 1
    trow = np.floor((l1 - lat) / res).astype(np.int64)
    hl = _heights(_spacing(lat, cloud.scan, cloud.step), res)
    top = _splat((th, w), col, trow, -z, colour, block, hl)

    cm = res * 100
    return np.vstack(
        [
            _band(w, title, scale=0.6),
            _band(w, f"the camera's side seen from the street ({cm:.0f} cm/px)", res),
            facade,
            _band(w, f"seen from above ({cm:.0f} cm/px); grey: points no frame saw", res),
            top,
        ]
    )


def preview_png(
    path: str | os.PathLike[str], cloud: Cloud, *, title: str = "", metres_per_px: float = 0.03
) -> tuple[int, int]:
    """Write :func:`preview_image` as a PNG; returns its (width, height), px."""
    img = preview_image(cloud, metres_per_px=metres_per_px, title=title)
    if not cv2.imwrite(str(path), img):
        raise OSError(f"{path}: cannot write the PNG")
    return int(img.shape[1]), int(img.shape[0])


def camera_calib(
    log: DriveLog, calib: Calibration, camera: str | None
) -> tuple[str, calibfile.CameraCalib]:
    """(name, calibration) of the camera to use: ``camera``, else the calibration's only
    one, else the log's camera. KeyError for an unknown camera; ValueError when the log
    has no frames."""
    if camera is None and len(calib.cameras) != 1 and log.camera:
        name = log.camera
    else:
        name = camera if camera is not None else next(iter(calib.cameras), "")
    cam = calib.camera(name)
    if not log.n_frames:
        raise ValueError("the log has no camera frames")
    return name, cam
