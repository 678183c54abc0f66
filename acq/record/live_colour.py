"""Live colouring: the recorder's scans coloured as they come, with the core ``acq colorize``
runs (:mod:`acq.cloud.scan_colouring`).

A :class:`LiveColourer` is a listener of the recorder's log (:mod:`acq.record.listeners`:
its own thread and bounded queue, so it never holds up a device or the writer). It keeps
the last frames of each calibrated camera and, with a :class:`acq.motion.rolling`
trajectory, the rig's poses; each scan waits until every camera has a frame after the
scan's last point (and the poses reach it), or ``wait_s`` after it, and is then coloured:
the nearest frame in time of every camera, motion compensated when the poses cover it,
the cameras merged. The result goes to ``emit`` as ``/<scanner>/colored``
(``foxglove.PointCloud`` in the laser frame: x, y, z float32, red, green, blue, alpha
uint8, alpha 0 where no camera saw the point; stamped with the scan's stamp) and its
coloured points to the :class:`acq.record.swath.Swath`, whose cloud goes to ``emit`` as
``/live/swath`` at 2 Hz. When colouring falls behind, the oldest waiting scans are
skipped (counted, with those its full queue lost), never a logged record.

Times: the records' stamps are on the log's clock (UTC for a recorder's log); they are
taken back to host ns as ``acq colorize`` reads them, and the messages made are stamped
on the log's clock again.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Executor, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from acq.camera.calibfile import Calibration
from acq.camera.jpeg import decode_jpeg
from acq.cloud import scan_colouring, views
from acq.geometry.transforms import Rigid
from acq.log import schemas
from acq.log.cloud_message import point_cloud
from acq.log.drive_log import ScanMessage, scan_message, stamp_ns
from acq.log.stamp_shift import stamps_to_host
from acq.log.vehicle_log import FIX_TOPIC, ODOMETRY_TOPIC
from acq.log.writer import LogWriter
from acq.motion import RollingTrajectory, Trajectory
from acq.record.device_loop import DeviceState, Outbox
from acq.record.listeners import Listener, LogRecord
from acq.record.swath import SPAN_S, Swath

if TYPE_CHECKING:
    from acq.record.recorder import Recorder

__all__ = [
    "LIVE_OPTIONS",
    "SWATH_TOPIC",
    "TF_TOPIC",
    "ColourSettings",
    "LiveColourer",
    "LivePoses",
    "attach",
    "coloured_topic",
]

log = logging.getLogger("acq.record")

LIVE_OPTIONS = views.Options(view="nearest", balance=False)  # what a scan alone allows
WAIT_S = 0.3  # s a scan waits after its last point for the frames (and poses) after it
MAX_WAITING = 12  # scans waiting at most (0.3 s at 40 Hz); older ones are skipped
# records queued for the colourer beyond which it skips ready scans rather than colour
# them (about 0.25 s of the simulated rig's records): the frames and poses behind them
# are taken at once, and its queue never fills (it would lose those)
BEHIND_RECORDS = 64
FRAMES_KEPT_S = 1.0  # s of each camera's frames kept before the newest
# s past the newest vehicle sample the poses extrapolate its motion: a trajectory rebuilt
# 0.2 s ago covers the scan that just ended (a car's motion changes little in that time)
POSE_MARGIN_S = 0.3
SHARE_SCANS = 40  # the coloured shares are those of the last this many scans
SWATH_TOPIC = "/live/swath"
TF_TOPIC = "/tf"  # the vehicle's pose in the poses' frame, at most TF_HZ
TF_HZ = 10.0
IMAGE_SUFFIX = "/image/compressed"
VEHICLE_TOPICS = RollingTrajectory.TOPICS
POSE_WINDOW_S = 20.0  # s of vehicle data the rolling trajectory is built from
POSE_REBUILD_S = 0.2  # s between two builds at least


def coloured_topic(scanner: str) -> str:
    """The topic of ``scanner``'s coloured scans."""
    return f"/{scanner}/colored"


class LivePoses(Protocol):
    """The rig's poses as they come (:class:`acq.motion.rolling.RollingTrajectory`)."""

    def add(self, topic: str, msg: Any) -> None: ...

    def current(self) -> Trajectory | None: ...

    def latest_ns(self) -> int | None: ...


@dataclass
class _Camera:
    name: str
    cam: Any  # CameraCalib
    offset_ns: int
    frames: deque[tuple[int, bytes]] = field(default_factory=deque)  # (stamp, JPEG)
    decoded: dict[int, np.ndarray | None] = field(default_factory=dict)  # stamp -> image

    def newest_on_laser_clock(self) -> int | None:
        return self.frames[-1][0] - self.offset_ns if self.frames else None

    def keep_from(self, lo_ns: int) -> None:
        """Forget the frames stamped before ``lo_ns``."""
        while self.frames and self.frames[0][0] < lo_ns:
            self.decoded.pop(self.frames.popleft()[0], None)

    def around(self, lo_ns: int, hi_ns: int) -> tuple[np.ndarray, list[views.Frame]]:
        """The stamps and decoded images of the frames stamped in [lo_ns, hi_ns]."""
        stamps, images = [], []
        for stamp, jpeg in self.frames:
            if lo_ns <= stamp <= hi_ns:
                if stamp not in self.decoded:
                    self.decoded[stamp] = decode_jpeg(jpeg)
                image = self.decoded[stamp]
                stamps.append(stamp)
                images.append(image if image is not None else b"")
        return np.array(stamps, dtype=np.int64), images


class LiveColourer(Listener):
    """Colours ``scanner``'s scans from the cameras of ``calibration`` (module docstring).
    ``emit`` takes the messages made (on this listener's thread); ``time_increment_s``
    gives the scanner's time between two points (s; None until it has connected: its
    scans wait); ``utc_offset_ns`` the log's clock less host ns."""

    def __init__(
        self,
        calibration: Calibration,
        scanner: str,
        *,
        emit: Callable[[LogRecord], None],
        time_increment_s: Callable[[], float | None],
        utc_offset_ns: Callable[[], int] = lambda: 0,
        poses: LivePoses | None = None,
        pose_topics: tuple[str, ...] = VEHICLE_TOPICS,
        swath: Swath | None = None,
        options: views.Options = LIVE_OPTIONS,
        wait_s: float = WAIT_S,
        threads: int = 0,
    ) -> None:
        self.scanner = scanner
        self.topic = coloured_topic(scanner)
        self.emit, self.time_increment_s, self.utc_offset_ns = emit, time_increment_s, utc_offset_ns
        self.poses, self.swath, self.options = poses, swath, options
        self.pose_topics = pose_topics
        self.wait_ns = round(wait_s * 1e9)
        self.l2v = calibration.laser_to_vehicle or Rigid.identity()
        self.cameras = {
            name: _Camera(name, cam, round(cam.time_offset_s * 1e9))
            for name, cam in calibration.cameras.items()
        }
        self._waiting: deque[ScanMessage] = deque()
        self._built: Trajectory | None = None  # the poses' last build, and it extended
        self._extended: Trajectory | None = None
        self._pool: Executor = (
            ThreadPoolExecutor(threads, thread_name_prefix="live colour")
            if threads > 0
            else scan_colouring.Inline()
        )
        self._now_ns = 0  # host ns of the newest record taken
        self._schema = schemas.SCHEMAS["foxglove.PointCloud"]
        self._tf_schema = schemas.SCHEMAS["foxglove.FrameTransforms"]
        self._tf_ns = -(2**62)  # the stamp of the last /tf sent
        self.coloured = 0  # scans coloured and emitted
        self.skipped = 0  # scans not coloured: colouring fell behind
        self.lost = 0  # scans that never reached it: its queue was full (writer's thread)
        self.failed = 0  # scans whose colouring raised
        # per scan of the last SHARE_SCANS: (points, points coloured by each camera)
        self._shares: deque[tuple[int, np.ndarray]] = deque(maxlen=SHARE_SCANS)
        self._warm = threading.Event()  # set: the kernels are ready (see start_warm_up)
        self._warm.set()

    # --- the kernels ----------------------------------------------------------------------

    def warm_up(self) -> float:
        """Colour one made-up scan (a 5 m circle) from a grey frame of each camera, nothing
        emitted: numba compiles the colouring kernels, or loads them from its cache, before
        a real scan waits on them. The seconds it took."""
        t0 = time.monotonic()
        steps = 1081
        beams = scan_colouring.Beams(-0.75 * np.pi, 1.5 * np.pi / (steps - 1), 25e-6)
        stamp = np.zeros(1, dtype=np.int64)
        cameras = []
        for c in self.cameras.values():
            grey = np.full((c.cam.model.height, c.cam.model.width, 3), 128, np.uint8)
            cameras.append(scan_colouring.camera_frames(c.name, c.cam, stamp, [grey], 0, None))
        options = replace(self.options, motion_compensation=False)
        scan_colouring.colour_scans(
            np.full((1, steps), 5.0), stamp, beams, cameras, None, self.l2v, options,
            pool=scan_colouring.Inline(),
        )  # fmt: skip
        return time.monotonic() - t0

    def start_warm_up(self) -> threading.Thread:
        """:meth:`warm_up` on a thread of its own. Until it has ended, scans are taken and
        wait (the oldest skipped, counted) rather than block this listener's thread on a
        compilation that takes seconds on a machine's first recording, its queue
        overflowing meanwhile."""
        self._warm.clear()

        def run() -> None:
            try:
                took = self.warm_up()
                level = logging.INFO if took > 1.0 else logging.DEBUG
                log.log(level, "live colouring ready: its kernels took %.1f s to load "
                        "(numba caches them once compiled)", took)  # fmt: skip
            except Exception as e:  # the scans' own colouring says what fails
                log.debug("live colouring: warm-up failed", exc_info=e)
            finally:
                self._warm.set()

        thread = threading.Thread(target=run, name="live colour warm-up", daemon=True)
        thread.start()
        return thread

    # --- taking records ------------------------------------------------------------------

    def on_record(self, record: LogRecord) -> None:
        topic = record.topic
        offset = self.utc_offset_ns()
        if topic == f"/{self.scanner}/scan":
            msg = self._decode(record, offset)
            if msg is not None:
                self._waiting.append(scan_message(msg))
                while len(self._waiting) > MAX_WAITING:
                    self._waiting.popleft()
                    self.skipped += 1
        elif topic.endswith(IMAGE_SUFFIX) and topic[1 : -len(IMAGE_SUFFIX)] in self.cameras:
            msg = self._decode(record, offset)
            if msg is not None:
                camera = self.cameras[topic[1 : -len(IMAGE_SUFFIX)]]
                camera.frames.append((stamp_ns(msg), bytes(msg.data)))
                camera.keep_from(camera.frames[-1][0] - round(FRAMES_KEPT_S * 1e9))
        elif topic in self.pose_topics and self.poses is not None:
            msg = self._decode(record, offset)
            if msg is not None:
                self.poses.add(topic, msg)
        else:
            return
        self._now_ns = max(self._now_ns, record.log_time_ns - offset)
        self._colour_ready(offset)

    def dropped(self, record: LogRecord) -> None:
        if record.topic == f"/{self.scanner}/scan":
            self.lost += 1

    @staticmethod
    def _decode(record: LogRecord, offset: int) -> Any:
        """The record's message, its foxglove stamps on host ns; None when it does not
        decode (the log has the record: its readers say so)."""
        try:
            msg = schemas.decode(record.schema.name, record.data)
        except Exception:
            return None
        stamps_to_host(msg, record.schema.name, offset)
        return msg

    # --- colouring -----------------------------------------------------------------------

    def _ready(self, scan: ScanMessage, end_ns: int) -> bool:
        """Whether every camera has a frame after ``scan``'s last point (at ``end_ns``)
        and the poses reach it, or the scan has waited long enough."""
        if self._now_ns - end_ns >= self.wait_ns:
            return True
        for camera in self.cameras.values():
            newest = camera.newest_on_laser_clock()
            if newest is None or newest < end_ns:
                return False
        if self.poses is not None and self.options.motion_compensation:
            traj = self._trajectory()
            return traj is not None and bool(traj.covers(np.array([end_ns]))[0])
        return True

    def _trajectory(self) -> Trajectory | None:
        """The poses' newest build, its motion extrapolated ``POSE_MARGIN_S`` past it."""
        traj = self.poses.current() if self.poses is not None else None
        if traj is not self._built:
            self._built = traj
            self._extended = replace(traj, margin_s=POSE_MARGIN_S) if traj is not None else None
        return self._extended

    def _colour_ready(self, offset: int, everything: bool = False) -> None:
        """Colour the waiting scans that are ready, in order (``everything``: all, with
        the frames there are: the log ends)."""
        if not everything and not self._warm.is_set():
            return  # the scans wait (the oldest skipped) until the kernels are ready
        while self._waiting:
            increment = self.time_increment_s()
            if increment is None:
                return
            scan = self._waiting[0]
            end_ns = scan.stamp_ns + round((scan.steps - 1) * increment * 1e9)
            if not everything and not self._ready(scan, end_ns):
                return
            self._waiting.popleft()
            if not everything and self.backlog() > BEHIND_RECORDS:
                self.skipped += 1  # behind: this scan's colour would come too late
                continue
            try:
                self._colour(scan, end_ns, increment, offset)
            except Exception as e:  # one scan lost, never the listener
                self.failed += 1
                if self.failed == 1:
                    log.warning("live colouring: scan not coloured: %s", e)
                log.debug("live colouring failed", exc_info=e)

    def _colour(self, scan: ScanMessage, end_ns: int, increment: float, offset: int) -> None:
        beams = scan_colouring.Beams(scan.start_angle, scan.angle_increment, increment)
        traj = self._trajectory()
        if traj is not None and not traj.covers(np.array([scan.stamp_ns, end_ns])).all():
            traj = None  # no pose yet (or a gap): coloured as the laser saw it
        margin = round((self.options.max_dt_s + 0.05) * 1e9)
        cameras = []
        for camera in self.cameras.values():
            lo, hi = scan.stamp_ns - margin, end_ns + margin
            stamps, images = camera.around(lo + camera.offset_ns, hi + camera.offset_ns)
            cameras.append(
                scan_colouring.camera_frames(
                    camera.name, camera.cam, stamps, images, camera.offset_ns, traj
                )
            )
        options = (
            self.options if traj is not None else replace(self.options, motion_compensation=False)
        )
        pts, merged = scan_colouring.colour_scans(
            scan.ranges[None, :], np.array([scan.stamp_ns], dtype=np.int64), beams, cameras,
            traj, self.l2v, options, pool=self._pool,
        )  # fmt: skip
        alpha = np.where(merged.coloured, 255, 0).astype(np.uint8)
        stamp_log = scan.stamp_ns + offset
        data = point_cloud(pts.P_laser, merged.rgb, self.scanner, stamp_log, alpha)
        self.emit(LogRecord(self.topic, self._schema, data, self._now_ns + offset))
        self.coloured += 1
        per_camera = np.bincount(merged.camera[merged.coloured], minlength=len(cameras))
        self._shares.append((pts.time_ns.size, per_camera))
        if traj is not None and scan.stamp_ns - self._tf_ns >= 1e9 / TF_HZ:
            self._tf_ns = scan.stamp_ns
            R, t = traj.pose_at(np.array([scan.stamp_ns]))
            tf = schemas.transform(traj.frame, "vehicle", Rigid(R[0], t[0]), stamp_log)
            self.emit(LogRecord(TF_TOPIC, self._tf_schema, tf, self._now_ns + offset))
        if self.swath is not None:
            world = traj is not None and self.options.motion_compensation
            xyz = pts.P_world if world else pts.P_laser
            frame = traj.frame if traj is not None and world else self.scanner
            c = merged.coloured
            self.swath.add(scan.stamp_ns, xyz[c], merged.rgb[c], frame)
            if self.swath.due(self._now_ns):
                cloud = self.swath.cloud(self._now_ns, stamp_log)
                self.emit(LogRecord(SWATH_TOPIC, self._schema, cloud, self._now_ns + offset))

    # --- figures -------------------------------------------------------------------------

    def shares(self) -> tuple[float, dict[str, float]]:
        """The share of the last scans' points coloured, and by each camera."""
        last = list(self._shares)  # another thread appends
        points = sum(n for n, _ in last)
        if not points:
            return 0.0, {name: 0.0 for name in self.cameras}
        by = np.sum([c for _, c in last], axis=0)
        names = list(self.cameras)
        return float(by.sum() / points), {
            name: float(by[k] / points) for k, name in enumerate(names)
        }

    def status(self) -> schemas.ColouringStatus:
        """The figures ``/acq/status`` carries each second (read from the writer's thread:
        counters and a copy of the last scans' shares); skipped counts the scans its full
        queue lost too."""
        share, by_camera = self.shares()
        skipped = self.skipped + self.lost
        return schemas.ColouringStatus(self.coloured, skipped, share, by_camera)

    def stop(self) -> None:
        """The log is closed: the scans still waiting are coloured with the frames there
        are (a drive's last scans have none after them)."""
        self._colour_ready(self.utc_offset_ns(), everything=True)
        self._pool.shutdown(wait=False, cancel_futures=True)


# --- in the recorder -------------------------------------------------------------------


@dataclass(frozen=True)
class ColourSettings:
    """What ``acq record`` asks of live colouring: ``log`` the coloured scans too
    (``--log-colored``); ``server`` the live server (``--live``) that gets the coloured
    scans (when not logged: a logged one reaches it through the log) and the swath of
    the last ``swath_s`` seconds."""

    log: bool = False
    server: Listener | None = None
    swath_s: float = SPAN_S


class _LogOutput:
    """The coloured scans into the log, through the recorder's outbox (the writer's
    thread writes them, as a device's records). Skipped, and counted, when the outbox is
    half full: the devices' records come first."""

    def __init__(self, outbox: Outbox) -> None:
        self.outbox = outbox
        self.name = "live colouring"
        self.state = DeviceState(self.name, "listener")
        self.registered = False
        self.skipped = 0

    def put(self, record: LogRecord) -> bool:
        """Queue ``record`` for the writer; False (counted) when the outbox is half full."""
        if self.outbox.qsize() * 2 >= self.outbox.queue.maxsize:
            self.skipped += 1
            return False
        self.outbox.put(self, record)  # type: ignore[arg-type]
        return True

    def write(self, writer: LogWriter, record: LogRecord) -> None:
        """On the writer's thread: the record at its log time (on the host clock)."""
        if not self.registered:
            writer.add_channel(record.topic, record.schema)
            self.registered = True
        host_ns = writer.time_base.to_host(record.log_time_ns)
        writer.write(record.topic, record.data, host_ns, host_ns)


def attach(recorder: Recorder, settings: ColourSettings) -> LiveColourer | None:
    """A :class:`LiveColourer` of ``recorder``'s first scanner on its log, sending what
    it makes where ``settings`` say; None (after one line saying why) when the recorder
    has no calibration with a camera, or no scanner."""
    calib = recorder.calibration
    if calib is None or not calib.cameras or not recorder.config.scanners:
        log.warning("live colouring off: %s", "no scanner" if calib and calib.cameras
                    else "no calibration with a camera (calibration: in the configuration, "
                    "or --calib)")  # fmt: skip
        return None
    scanner = recorder.config.scanners[0].name
    adapter = next(a for a in recorder.adapters if a.name == scanner)

    def time_increment() -> float | None:
        geometry = getattr(adapter.device, "geometry", None)
        return float(geometry.time_increment) if geometry is not None else None

    def utc_offset() -> int:
        writer = recorder.writer
        return writer.time_base.utc_offset_ns if writer is not None else 0

    server = next((f for f in recorder.listeners.feeds if f.listener is settings.server), None)
    to_log = _LogOutput(recorder.outbox) if settings.log else None

    def emit(record: LogRecord) -> None:
        if record.topic == coloured_topic(scanner) and to_log is not None and to_log.put(record):
            return  # the server, if any, has it from the log
        if server is not None:
            server.put(record)

    poses: RollingTrajectory | None = None
    topics: tuple[str, ...] = ()
    if recorder.config.can is not None or recorder.config.gnss is not None:
        # with wheel odometry, it alone: exact over the milliseconds between a point and
        # its frame, and a rebuild of dead reckoning costs little (a fusion with the
        # fixes costs ten times more, for a swath placed better)
        topics = (ODOMETRY_TOPIC,) if recorder.config.can is not None else (FIX_TOPIC,)
        poses = RollingTrajectory(window_s=POSE_WINDOW_S, rebuild_s=POSE_REBUILD_S)
    colourer = LiveColourer(
        calib, scanner, emit=emit, time_increment_s=time_increment, utc_offset_ns=utc_offset,
        poses=poses, pose_topics=topics,
        swath=Swath(settings.swath_s) if server is not None else None,
    )  # fmt: skip
    colourer.start_warm_up()
    recorder.listeners.add(colourer)
    log.info("live colouring %s from %s%s", scanner, ", ".join(calib.cameras),
             " (logged too)" if to_log else "")  # fmt: skip
    return colourer
