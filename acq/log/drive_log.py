"""A recorded drive as numpy arrays, for placing and colouring its points.

Reading (:func:`read_log`): ``/<laser>/scan`` (``foxglove.LaserScan``: the timestamp is
the host time of point 0), the scanner's ``device.<laser>`` metadata (``geometry``:
``time_increment`` s per point), ``/<camera>/image/compressed`` (stamped at the middle
of the exposure), the ``/acq/timing/*`` records (device ticks, frame sequence numbers),
the ``/acq/clock`` (UTC, monotonic) pairs and the ``calibration`` metadata.

Times are host ``CLOCK_MONOTONIC`` ns (int64) unless a name ends in ``_s``.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from acq.camera import calibfile
from acq.camera.calibfile import Calibration
from acq.camera.selection import choose_cameras
from acq.drivers.errors import ProtocolError
from acq.drivers.mjpeg import jpeg_size
from acq.errors import InputValueError
from acq.log.reader import LogReader, read_metadata
from acq.log.vehicle_log import VehicleLog, VehicleReader


@dataclass(frozen=True)
class CameraFrames:
    """One camera's frames in a log: ``frame_ns`` (F,) host ns of the middle of
    exposure, sorted; ``frame_seq`` (F,) the driver's sequence numbers (-1 where unknown;
    they restart on a reconnect); ``frame_recv_ns`` (F,) receipt (-1 where unknown);
    ``jpegs`` the bytes as the camera sent them (empty when read without them);
    ``size`` (width, height) px of the first frame read whose JPEG header parses (None:
    none did)."""

    frame_ns: np.ndarray
    frame_seq: np.ndarray
    frame_recv_ns: np.ndarray
    jpegs: list[bytes]
    size: tuple[int, int] | None = None

    @staticmethod
    def empty() -> CameraFrames:
        none = np.zeros(0, np.int64)
        return CameraFrames(none, none, none, [])

    def between(self, lo_ns: int, hi_ns: int) -> CameraFrames:
        """The frames stamped in [lo_ns, hi_ns)."""
        f = np.flatnonzero((self.frame_ns >= lo_ns) & (self.frame_ns < hi_ns))

        def part(a: np.ndarray) -> np.ndarray:
            return a[f] if a.size else a

        return CameraFrames(
            frame_ns=self.frame_ns[f],
            frame_seq=part(self.frame_seq),
            frame_recv_ns=part(self.frame_recv_ns),
            jpegs=[self.jpegs[int(i)] for i in f] if self.jpegs else [],
            size=self.size,
        )


@dataclass(frozen=True)
class DriveLog:
    """What colouring needs from one log or the split files of one session.

    Scans: ``scan_ns`` (S,) host ns of point 0; ``ranges`` and ``intensities`` (S, N)
    float32 (REP-117 ranges, m; intensities zero where the device sends none);
    ``angle_min``, ``angle_increment`` rad and ``time_increment`` s per point;
    ``scan_ticks`` (S,) the device clock tick of each scan (-1 where unknown). Frames:
    ``cameras`` every camera read, by name (:class:`CameraFrames`); ``camera`` the one
    that ``frame_ns``, ``frame_seq``, ``frame_recv_ns`` and ``jpegs`` are of ("" for a
    log without frames; :meth:`with_camera` picks another). ``clock`` (K,2) int64 pairs
    (monotonic ns, realtime ns). ``metadata`` by name (the last record of each name).
    ``vehicle``: the odometry and GNSS fixes (:class:`acq.log.vehicle_log.VehicleLog`)
    when read with them. ``camera_names``: every camera the log has frames of, read or
    not.
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
    cameras: dict[str, CameraFrames]
    clock: np.ndarray
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)  # what was missing and assumed
    scan_recv_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    vehicle: VehicleLog | None = None
    camera_names: tuple[str, ...] = ()  # every camera with frames in the log, read or not
    steps: int = 0  # the points a scan has (``ranges``' columns unless read without them)
    # read with images for a first span only: those received before this log time have
    # their bytes, the others b"" (None: every frame's or none, as ``jpegs`` was)
    jpegs_until_ns: int | None = None

    @property
    def frames(self) -> CameraFrames:
        """The frames of ``camera``."""
        return self.cameras.get(self.camera) or CameraFrames.empty()

    @property
    def frame_ns(self) -> np.ndarray:
        return self.frames.frame_ns

    @property
    def frame_seq(self) -> np.ndarray:
        return self.frames.frame_seq

    @property
    def frame_recv_ns(self) -> np.ndarray:
        return self.frames.frame_recv_ns

    @property
    def jpegs(self) -> list[bytes]:
        return self.frames.jpegs

    @property
    def n_scans(self) -> int:
        return int(self.scan_ns.size)

    @property
    def n_frames(self) -> int:
        return int(self.frame_ns.size)

    def with_camera(self, name: str) -> DriveLog:
        """This log with ``camera`` = ``name`` (one of ``cameras``)."""
        if name not in self.cameras:
            raise InputValueError(
                f"no camera {name!r} in the log (has {', '.join(sorted(self.cameras)) or 'none'})"
            )
        return replace(self, camera=name)

    def with_frames(self, **changes: Any) -> DriveLog:
        """This log with fields of ``camera``'s :class:`CameraFrames` replaced."""
        frames = replace(self.frames, **changes)
        return replace(self, cameras={**self.cameras, self.camera: frames})

    def between(self, lo_ns: int, hi_ns: int) -> DriveLog:
        """The scans and frames stamped in [lo_ns, hi_ns) (recorded stamps)."""
        s = (self.scan_ns >= lo_ns) & (self.scan_ns < hi_ns)

        def part(a: np.ndarray) -> np.ndarray:
            return a[s] if a.size else a

        return replace(
            self,
            scan_ns=self.scan_ns[s],
            ranges=self.ranges[s],
            intensities=self.intensities[s],
            scan_ticks=part(self.scan_ticks),
            scan_recv_ns=part(self.scan_recv_ns),
            cameras={name: c.between(lo_ns, hi_ns) for name, c in self.cameras.items()},
        )


def _pick(found: Iterable[str], name: str | None, what: str, topic: str) -> str:
    """The device ``name``, or the only one ``found``; InputValueError naming the choices."""
    names = sorted(found)
    if name is not None:
        if name not in names:
            raise InputValueError(
                f"no {what} {name!r} in the log (has {', '.join(names) or 'none'})"
            )
        return name
    if not names:
        raise InputValueError(f"no {what} in the log (no /<name>{topic} messages)")
    if len(names) > 1:
        raise InputValueError(f"the log has several {what}s ({', '.join(names)}); name one")
    return names[0]


def _no_scans_because(undecodable: dict[str, int], why: dict[str, str]) -> None:
    """No scan decoded: InputValueError naming the scan topics whose messages did not
    decode (``undecodable``: topic -> messages), if any, and why (``why``: topic ->
    ``FILE: reason``, the first file's)."""
    lost = {t: n for t, n in undecodable.items() if t.endswith("/scan")}
    if lost:
        counts = "; ".join(
            f"{n} {t} messages cannot be decoded" + (f": {why[t]}" if t in why else "")
            for t, n in sorted(lost.items())
        )
        raise InputValueError(f"no laser scan in the log decodes ({counts})")


@dataclass(frozen=True)
class ScanMessage:
    """One ``foxglove.LaserScan`` as colouring needs it: its stamp (ns, the log's clock),
    ranges (m) and intensities float32 (empty when read without the returns), first and
    last angles (rad) and its number of points."""

    stamp_ns: int
    ranges: np.ndarray
    intensities: np.ndarray
    start_angle: float
    end_angle: float
    steps: int

    @property
    def angle_increment(self) -> float:
        """rad between two points (0 for a scan of one point)."""
        n = self.steps
        return (self.end_angle - self.start_angle) / (n - 1) if n > 1 else 0.0


def scan_message(msg: Any, returns: bool = True) -> ScanMessage:
    """A decoded ``foxglove.LaserScan`` as a :class:`ScanMessage` (``returns=False``:
    without its ranges and intensities). AttributeError for a message of another schema."""
    return ScanMessage(
        stamp_ns(msg),
        np.asarray(msg.ranges, dtype=np.float32) if returns else _NONE,
        np.asarray(msg.intensities, dtype=np.float32) if returns else _NONE,
        float(msg.start_angle),
        float(msg.end_angle),
        len(msg.ranges),
    )


_NONE = np.zeros(0, dtype=np.float32)


def stamp_ns(msg: Any) -> int:
    """A foxglove message's ``timestamp`` in ns (the log's clock)."""
    return int(msg.timestamp.seconds) * 10**9 + int(msg.timestamp.nanos)


def _stamp_of(message: Any) -> int:
    """An MCAP message's publish time: the recorder puts the stamp there."""
    return int(message.publish_time)


def read_log(
    paths: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    *,
    laser: str | None = None,
    camera: str | None = None,
    cameras: Sequence[str] | None = None,
    start_ns: int | None = None,
    end_ns: int | None = None,
    jpegs: bool = True,
    returns: bool = True,
    vehicle: bool = False,
    calib: Calibration | None = None,
    jpegs_for_s: float | None = None,
    jpegs_at: Mapping[str, Collection[int]] | None = None,
) -> DriveLog:
    """Scans, frames, clock pairs and metadata of a log (or of a session's files, in the
    order given). ``laser``/``camera`` name the devices where the log has several;
    ``cameras``: the cameras to read (the first is ``camera`` unless it is named; the
    log may lack some: they read with no frames); by default only ``camera``.
    ``start_ns``/``end_ns``: only messages received (MCAP log time) in that span, and
    only the chunks of a closed file that hold some (a long log's part reads in the
    time of that part): the clock pairs, and with ``vehicle`` the odometry and GNSS
    fixes, whatever their time in those chunks; metadata whatever their time.
    ``jpegs=False`` leaves the images' bytes out (their stamps stay); ``returns=False``
    the scans' ranges and intensities (``ranges`` and ``intensities`` are then (S, 0);
    ``steps`` keeps the points a scan has): a long log's index then holds its times and
    no more, a few bytes a scan instead of 8 a point; ``vehicle``: also
    the odometry and GNSS fixes, in the same pass, as
    :func:`acq.log.vehicle_log.read_vehicle`. ``calib``: the cameras read are then
    those :func:`acq.camera.selection.choose_cameras` picks from the log's and
    ``calib``'s, ``camera`` or ``cameras`` being what ``--camera`` asked (with
    ``cameras``, every camera of both when it is empty). ``jpegs_for_s``: with ``jpegs``,
    only the images received in the first that many seconds (log time from the first
    message read) keep their bytes (the first chunks of a long log, without reading it
    twice); the log's ``jpegs_until_ns`` says up to when. ``jpegs_at``: with ``jpegs``,
    only the images of these cameras (by name) recorded at these stamps keep their bytes
    (a few frames of a long window, without holding every image in memory).

    Files whose writer was killed are read up to their last good record
    (:class:`acq.log.LogReader`); undecodable messages are skipped (noted).
    Raises :class:`acq.log.LogError` for a file that is not MCAP, InputValueError
    when the log has no scans or several lasers/cameras. A log without frames reads with
    ``camera`` "" and no frames.
    """
    if isinstance(paths, str | os.PathLike):
        files: tuple[Path, ...] = (Path(paths),)
    else:
        files = tuple(Path(p) for p in paths)
    metadata: dict[str, dict[str, str]] = {}
    scans: dict[str, list[ScanMessage]] = {}
    frames: dict[str, list[tuple[int, bytes]]] = {}
    sizes: dict[str, tuple[int, int] | None] = {}  # by camera: its first frame's
    timing: dict[str, dict[int, tuple[int, int, int]]] = {}  # stamp -> (tick, seq, recv)
    lo = -(2**63) if start_ns is None else start_ns
    hi = 2**63 - 1 if end_ns is None else end_ns
    clock: list[tuple[int, int]] = []
    bad = 0
    undecodable: dict[str, int] = {}  # by topic, every file's
    undecodable_why: dict[str, str] = {}  # by topic: "FILE: reason", the first file's
    vehicle_reader = VehicleReader() if vehicle else None
    vehicle_topics = VehicleReader.TOPICS if vehicle else ()
    span = None if start_ns is None and end_ns is None else (lo, hi)
    jpegs_until: int | None = None  # set at the first message, with jpegs_for_s
    for path in files:
        metadata.update(read_metadata(path))
        reader = LogReader(path, span)
        for schema, channel, message in reader.messages():
            topic = channel.topic
            if topic in vehicle_topics and vehicle_reader is not None:
                vehicle_reader.add(topic, reader.decode(schema, channel, message))
                continue
            wanted = topic.endswith(("/scan", "/image/compressed")) or topic.startswith(
                ("/acq/clock", "/acq/timing/")
            )
            if not wanted or (
                not lo <= message.log_time <= hi and not topic.startswith("/acq/clock")
            ):
                continue
            if jpegs_for_s is not None and jpegs_until is None:
                jpegs_until = message.log_time + round(jpegs_for_s * 1e9)
            if topic.endswith("/image/compressed"):
                name = topic[1:].removesuffix("/image/compressed")
                if (
                    not jpegs
                    or (jpegs_until is not None and message.log_time >= jpegs_until)
                    or (jpegs_at is not None and _stamp_of(message) not in jpegs_at.get(name, ()))
                ):
                    frames.setdefault(name, []).append((_stamp_of(message), b""))
                    if sizes.get(name) is None:
                        sizes[name] = _jpeg_size(reader.decode(schema, channel, message))
                    continue
            msg = reader.decode(schema, channel, message)
            if msg is None:
                bad += 1
                continue
            try:
                if topic.endswith("/scan"):
                    scans.setdefault(topic[1:].removesuffix("/scan"), []).append(
                        scan_message(msg, returns)
                    )
                elif topic.endswith("/image/compressed"):
                    name = topic[1:].removesuffix("/image/compressed")
                    frames.setdefault(name, []).append((stamp_ns(msg), bytes(msg.data)))
                    if sizes.get(name) is None:
                        sizes[name] = _jpeg_size(msg)
                elif topic == "/acq/clock":
                    clock.append((int(msg.monotonic_ns), int(msg.realtime_ns)))
                elif topic.startswith("/acq/timing/"):
                    ticks = list(msg.device_ticks)
                    timing.setdefault(topic.removeprefix("/acq/timing/"), {})[int(msg.stamp_ns)] = (
                        int(ticks[0]) if ticks else -1,
                        int(msg.sequence),
                        int(msg.recv_ns),
                    )
            except AttributeError:  # a message of another schema on a topic of that name
                bad += 1
        for topic, n in reader.undecodable.items():
            undecodable[topic] = undecodable.get(topic, 0) + n
            undecodable_why.setdefault(topic, f"{path}: {reader.why_undecodable(topic)}")
    if not scans:
        _no_scans_because(undecodable, undecodable_why)
    laser = _pick(scans, laser, "laser scanner", "/scan")
    found = tuple(sorted(n for n, f in frames.items() if f))
    if calib is not None:
        several = cameras is not None
        asked = list(cameras or ()) if several else [camera] if camera else None
        picked = choose_cameras(
            asked, found, list(calib.cameras), one=not several, calib=calib.label
        )
        names = [n for n, _ in picked]
        camera = names[0]
    elif cameras:
        camera = camera or cameras[0]
        names = list(dict.fromkeys([camera, *cameras]))
    else:
        camera = "" if camera is None and not frames else _pick(frames, camera, "camera", "/image")
        names = [camera] if camera else []
    notes = [f"{bad} undecodable messages skipped"] if bad else []
    log = _assemble(
        files,
        laser,
        camera,
        scans[laser],
        {name: frames.get(name, []) for name in names},
        sizes,
        timing,
        clock,
        metadata,
        notes,
    )
    log = replace(log, camera_names=found, jpegs_until_ns=jpegs_until if jpegs else None)
    if vehicle_reader is not None:
        log = replace(log, vehicle=vehicle_reader.result(files))
    return log


def _assemble(
    files: tuple[Path, ...],
    laser: str,
    camera: str,
    scans: list[ScanMessage],
    frames: dict[str, list[tuple[int, bytes]]],
    sizes: dict[str, tuple[int, int] | None],
    timing: dict[str, dict[int, tuple[int, int, int]]],
    clock: list[tuple[int, int]],
    metadata: dict[str, dict[str, str]],
    notes: list[str],
) -> DriveLog:
    scans.sort(key=lambda m: m.stamp_ns)
    n = max(m.steps for m in scans)
    first = next(m for m in scans if m.steps == n)
    angle_min = first.start_angle
    inc = first.angle_increment
    held = n if first.ranges.size else 0  # read without the returns: none held
    ranges = np.full((len(scans), held), np.nan, dtype=np.float32)
    intens = np.zeros((len(scans), held), dtype=np.float32)
    for k, m in enumerate(scans):
        if m.steps != n:  # a cropped scan after a reconfiguration: not placed
            notes.append(f"scan {k} has {m.steps} points, not {n}: skipped")
            continue
        if held:
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
        cameras={
            name: _camera_frames(f, timing.get(name, {}), sizes.get(name))
            for name, f in frames.items()
        },
        clock=np.array(clock, dtype=np.int64).reshape(-1, 2),
        metadata=metadata,
        notes=notes,
        scan_recv_ns=scan_recv,
        steps=n,
    )


def _jpeg_size(msg: Any) -> tuple[int, int] | None:
    """(width, height) px of a decoded image message's JPEG; None when it has none that
    parses (the decoder reports those)."""
    try:
        return jpeg_size(bytes(msg.data))
    except (ProtocolError, AttributeError):
        return None


def _camera_frames(
    frames: list[tuple[int, bytes]],
    timing: dict[int, tuple[int, int, int]],
    size: tuple[int, int] | None = None,
) -> CameraFrames:
    """One camera's (stamp, JPEG) messages and its timing records, in stamp order."""
    frames.sort(key=lambda f: f[0])
    frame_ns = np.array([t for t, _ in frames], dtype=np.int64)
    seq = np.array([timing.get(int(t), (0, -1, -1))[1] for t in frame_ns], dtype=np.int64)
    recv = np.array([timing.get(int(t), (0, -1, -1))[2] for t in frame_ns], dtype=np.int64)
    return CameraFrames(frame_ns, seq, recv, [j for _, j in frames], size)


# --- colouring -------------------------------------------------------------------------


def camera_calib(
    log: DriveLog, calib: Calibration, camera: str | None
) -> tuple[str, calibfile.CameraCalib]:
    """(name in the calibration, calibration) of ``log``'s camera: ``camera``, else the
    one :func:`acq.camera.selection.choose_cameras` picks from the log's and the
    calibration's names. CameraChoiceError (InputValueError) listing them when none
    fits, or the log has no frames."""
    in_log = [log.camera] if log.camera else []
    [(_, name)] = choose_cameras(
        [camera] if camera else None, in_log, list(calib.cameras), one=True, calib=calib.label
    )
    if not log.n_frames:
        raise InputValueError("the log has no camera frames")
    cam = calib.cameras[name]
    check_frame_size(log, log.camera or name, cam)
    return name, cam


def check_frame_size(log: DriveLog, name: str, cam: calibfile.CameraCalib) -> None:
    """InputValueError naming the calibration file, the camera and both sizes when the
    log's frames of camera ``name`` (its first frame's size) are not the size ``cam`` was
    calibrated at: a calibration of another camera or resolution."""
    size = log.cameras.get(name, log.frames).size  # a lone camera pairs whatever its name
    want = (cam.model.width, cam.model.height)
    if size is None or size == want:
        return
    files = ", ".join(p.name for p in log.files[:2]) + (" ..." if len(log.files) > 2 else "")
    raise InputValueError(
        f"{cam.source or 'calib.yaml'}: cameras.{cam.name or name}.image_size is "
        f"{want[0]}x{want[1]} px but the log's frames of camera {name} are {size[0]}x{size[1]}"
        f" ({files}): a calibration of another camera or resolution"
    )
