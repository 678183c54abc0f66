"""A drive (one session's ``.mcap`` logs) as the page draws it: the trajectory, a camera
frustum per camera pose along it, and its coloured cloud, found beside the log or made by
`acq colorize`'s core on a thread into a cache file.

The log is read, re-timed and given its trajectory as `acq colorize` does
(:func:`acq.cloud.job.prepare`), so everything lies in the colourer's world frame, on the
cloud. Times host monotonic ns unless ``_s``; metres."""

from __future__ import annotations

import functools
import hashlib
import os
import struct
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from acq.camera import calibfile
from acq.camera.calibfile import Calibration
from acq.cloud.job import Job, prepare
from acq.cloud.report import Report
from acq.cloud.views import camera_poses
from acq.errors import AcqError, InputError, first_line
from acq.log.drive_log import DriveLog, read_log
from acq.log.inputs import session_files
from acq.motion import Trajectory
from acq.motion.pose_source import trajectory_from_vehicle
from acq.time import sync
from acq.time.utc import utc_seconds

__all__ = [
    "CALIB_NAME",
    "CAMERA_COLOURS",
    "FRUSTUM_STEP_M",
    "TRAJECTORY_STEP_M",
    "Drive",
    "cache_dir",
    "spaced",
]

CALIB_NAME = "calib.yaml"  # the calibration looked for beside the log
FRUSTUM_STEP_M = 2.0  # one frustum per camera every this many metres of its travel
TRAJECTORY_STEP_M = 0.2  # the trajectory's polyline keeps a vertex every this many metres
# each camera's frustums in its own colour (sRGB), in the calibration's order
CAMERA_COLOURS = ("#ff4fd8", "#2fd3ff", "#ffe23a", "#7dff5a", "#ff8a2f", "#b48cff")
_T = TypeVar("_T")
_SPAN_SLACK_S = 1.0  # a cloud's first/last point may lie this far outside the log's span


def cache_dir() -> Path:
    """Where clouds made for `acq view` are kept: $XDG_CACHE_HOME/acq/view (default
    ~/.cache/acq/view)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "acq" / "view"


def spaced(xyz: np.ndarray, step_m: float) -> np.ndarray:
    """Indices of the rows of ``xyz`` (N,3) m kept so that each is at least ``step_m``
    from the one kept before it (the first always; the last too when it moved)."""
    keep = [0] if len(xyz) else []
    for i in range(1, len(xyz)):
        if np.linalg.norm(xyz[i] - xyz[keep[-1]]) >= step_m:
            keep.append(i)
    if len(xyz) > 1 and keep[-1] != len(xyz) - 1 and np.any(xyz[-1] != xyz[keep[-1]]):
        keep.append(len(xyz) - 1)
    return np.asarray(keep, dtype=np.int64)


@dataclass(frozen=True)
class _CloudState:
    """The drive's cloud: ``status`` "none" (``message`` why), "found" or "ready" (at
    ``path``), "making" (``progress`` 0-1) or "failed" (``message``)."""

    status: str
    path: Path | None = None
    progress: float = 0.0
    message: str = ""


class Drive:
    """The drive of the logs ``paths`` (a session's files or a folder of them), read and
    re-timed on construction (InputError naming a bad log or calibration). ``calib``:
    the calibration (default ``calib.yaml`` beside the first log, when there is one);
    without one, only the trajectory. The cloud (:meth:`cloud`) is one found beside the
    log (:meth:`found_cloud`), else made by :meth:`start` into ``cache`` (default
    :func:`cache_dir`)."""

    def __init__(
        self, paths: Sequence[Path], calib: Path | None = None, cache: Path | None = None
    ) -> None:
        self.files = session_files(paths)
        self.notes: list[str] = []
        beside = self.files[0].parent / CALIB_NAME
        self.calib_path = calib if calib is not None else (beside if beside.is_file() else None)
        self.calib: Calibration | None = None
        self.job: Job | None = None
        self._cache = cache if cache is not None else cache_dir()
        # no camera's frames ("" is how the reader names a log's lack of one): their names
        # only, whatever their number
        light = self._named(
            lambda: read_log(self.files, cameras=[""], jpegs=False, returns=False, vehicle=True)
        )
        self.clock = light.clock
        self.span_ns = (int(light.scan_ns.min()), int(light.scan_ns.max()))
        self.camera_names = light.camera_names
        if self.calib_path is None:
            self.notes.append(
                f"no calibration ({CALIB_NAME} beside the log, or --calib): the trajectory "
                "alone, without camera frustums or a coloured cloud"
            )
            self.trajectory = self._trajectory_of(light)
        else:
            self.calib = loaded = calibfile.load(self.calib_path)  # CalibFileError names it
            if light.camera_names:
                report = Report(output="")
                self.job, _ = self._named(lambda: prepare(self.files, loaded, report))
                self.notes += [n for n in report.notes if "no trajectory" not in n]
            else:
                self.notes.append("the log has no camera frames: no camera frustums")
            self.trajectory = self.job.trajectory if self.job else self._trajectory_of(light)
        if self.trajectory is None:
            self.notes.append(
                "no trajectory (the log has no CAN odometry or GNSS fixes): no path, no "
                "camera frustums, and a cloud in the laser frame"
            )
        self._lock = threading.Lock()
        self._state = self._first_state()
        self._thread: threading.Thread | None = None

    def _named(self, read: Callable[[], _T]) -> _T:
        """``read()``, its InputError or ValueError (odometry or fixes the trajectory
        cannot use) an InputError naming the log (some of the reader's do not)."""
        try:
            return read()
        except (InputError, ValueError) as e:
            text = first_line(e)
            raise InputError(
                text if str(self.files[0]) in text else f"{self.files[0]}: {text}"
            ) from None

    def _trajectory_of(self, light: DriveLog) -> Trajectory | None:
        """The trajectory `acq colorize` would make from the log's vehicle data."""
        vehicle = light.vehicle
        if vehicle is None:
            return None
        chosen = self._named(lambda: trajectory_from_vehicle(vehicle))
        self.notes += chosen.notes
        return chosen.trajectory

    @property
    def name(self) -> str:
        return self.files[0].name

    # the layer's data ----------------------------------------------------------------

    @functools.cached_property
    def _layer(self) -> dict[str, Any]:
        return {"path": self.path().tolist(), "frustums": self.frustums()}

    def path(self) -> np.ndarray:
        """The vehicle's origin along the drive, (N,3) m in the world frame, a vertex
        every :data:`TRAJECTORY_STEP_M`; empty without a trajectory."""
        if self.trajectory is None:
            return np.zeros((0, 3))
        _, p = self.trajectory.pose_at(self.trajectory.t_ns)
        return np.asarray(p[spaced(p, TRAJECTORY_STEP_M)])

    def frame_times(self, camera: int) -> np.ndarray:
        """Camera ``camera``'s (index in the job) frames' times on the laser's clock,
        re-timed, by session frame index (ns)."""
        assert self.job is not None
        cj = self.job.cameras[camera]
        return np.asarray(sync.on_laser_clock(cj.frame_new, cj.time_offset_ns))

    def frame_poses(self, camera: int, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rotations (M,3,3) and positions (M,3) m of camera ``camera``'s ``frames``
        (session indices) in the world frame: the trajectory at each frame's re-timed
        time composed with laser_to_vehicle and the camera's camera_to_laser."""
        assert self.job is not None and self.trajectory is not None
        cj = self.job.cameras[camera]
        t = self.frame_times(camera)[frames]
        return camera_poses(cj.cam, self.job.laser_to_vehicle, self.trajectory.pose_at, t)

    def frustums(self) -> list[dict[str, Any]]:
        """Per camera: its name, colour, image size and the poses of its frames one every
        :data:`FRUSTUM_STEP_M` of its travel (``frames`` session indices, ``R`` row-major
        rotations camera -> world, ``p`` positions m)."""
        if self.job is None or self.trajectory is None:
            return []
        out = []
        for c, cj in enumerate(self.job.cameras):
            covered = np.flatnonzero(self.trajectory.covers(self.frame_times(c)))
            R, p = self.frame_poses(c, covered)
            keep = spaced(p, FRUSTUM_STEP_M)
            out.append({
                "camera": cj.name,
                "colour": CAMERA_COLOURS[c % len(CAMERA_COLOURS)],
                "size": [cj.cam.model.width, cj.cam.model.height],
                "frames": covered[keep].tolist(),
                "R": R[keep].reshape(-1, 9).tolist(),
                "p": p[keep].tolist(),
            })  # fmt: skip
        return out

    def data(self) -> dict[str, Any]:
        """What ``/data/<k>/drive.json`` answers: the files, the world frame, the path,
        the frustums, the cloud's state and the notes."""
        frame = None if self.trajectory is None else str(self.trajectory.frame)
        return {
            "files": [f.name for f in self.files],
            "calib": None if self.calib_path is None else str(self.calib_path),
            "frame": frame,
            **self._layer,  # computed once: the page polls while the cloud is made
            "cloud": self.cloud_state(),
            "notes": self.notes,
        }

    # the cloud -----------------------------------------------------------------------

    def found_cloud(self) -> Path | None:
        """The cloud made from this log that lies beside it: a PLY `acq colorize` wrote
        in the log's folder whose first and last points' times (UTC) lie within the log's
        scans' span (a second's slack); the newest of several; None when there is none."""
        lo, hi = utc_seconds(np.array(self.span_ns), self.clock).tolist()
        found = []
        for path in self.files[0].parent.glob("*.ply"):
            span = _ply_time_span(path)
            if span is not None and lo - _SPAN_SLACK_S <= span[0] and span[1] <= hi + _SPAN_SLACK_S:
                found.append(path)
        return max(found, key=lambda p: p.stat().st_mtime_ns, default=None)

    def cache_path(self) -> Path:
        """The file a cloud made for this drive is kept in: named by a hash of the logs'
        paths, sizes and times and of the calibration's bytes."""
        h = hashlib.sha256()
        for f in self.files:
            st = f.stat()
            h.update(f"{f.resolve()}\0{st.st_size}\0{st.st_mtime_ns}\0".encode())
        if self.calib_path is not None:
            h.update(self.calib_path.read_bytes())
        return self._cache / f"{self.files[0].stem}-{h.hexdigest()[:16]}.ply"

    def _first_state(self) -> _CloudState:
        found = self.found_cloud()
        if found is not None:
            return _CloudState("found", found)
        if self.job is None:
            why = "no calibration" if self.calib is None else "no camera frames in the log"
            return _CloudState("none", message=f"no cloud beside the log, and {why} to colour one")
        cached = self.cache_path()
        if cached.is_file():
            return _CloudState("ready", cached)
        return _CloudState("making")

    def cloud_state(self) -> dict[str, Any]:
        """The cloud's state for the page: status, its file's name, progress, message."""
        with self._lock:
            s = self._state
        return {
            "status": s.status,
            "file": None if s.path is None else s.path.name,
            "progress": round(s.progress, 3),
            "message": s.message,
        }

    def cloud(self) -> Path | None:
        """The cloud's file once there is one (found, or made), else None."""
        with self._lock:
            return self._state.path if self._state.status in ("found", "ready") else None

    def start(self) -> None:
        """Make the cloud on a thread when it is to be made (no-op otherwise)."""
        with self._lock:
            if self._state.status != "making" or self._thread is not None:
                return
            self._thread = threading.Thread(target=self._make, name="acq-view-cloud", daemon=True)
        self._thread.start()

    def wait(self, timeout_s: float | None = None) -> None:
        """Wait for the cloud being made (tests, and the end of the server)."""
        if self._thread is not None:
            self._thread.join(timeout_s)

    def _make(self) -> None:
        from acq.cloud import colorize
        from acq.cloud.chunks import plan

        assert self.job is not None and self.calib is not None
        out = self.cache_path()
        chunks = max(1, len(plan(np.sort(self.job.scan_new), colorize.CHUNK_S)))
        counter = _ChunkCounter(lambda n: self._set(_CloudState("making", progress=n / chunks)))
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
            colorize.run(self.files, self.calib, out, results=counter)
        except (AcqError, OSError, ValueError) as e:  # a full disk among them
            self._set(_CloudState("failed", message=f"colouring the cloud: {first_line(e)}"))
        except BaseException as e:  # a fault of ours: the page is told, the traceback kept
            self._set(_CloudState("failed", message=f"colouring the cloud failed: {e!r}"))
            raise
        else:
            self._set(_CloudState("ready", out, progress=1.0))

    def _set(self, state: _CloudState) -> None:
        with self._lock:
            self._state = state


class _ChunkCounter(list[Any]):
    """A list colorize.run appends each chunk's result to, holding none of them: it only
    counts them (``tell(count)``), so a long drive's cloud is not held in memory."""

    def __init__(self, tell: Callable[[int], None]) -> None:
        super().__init__()
        self.chunks, self._tell = 0, tell

    def append(self, item: Any) -> None:
        self.chunks += 1
        self._tell(self.chunks)


def _ply_time_span(path: Path) -> tuple[float, float] | None:
    """The UTC times (s) of the first and last points of a cloud `acq colorize` wrote as
    PLY; None for any other file (or one that cannot be read)."""
    from plyfile import PlyData, PlyParseError

    try:
        with open(path, "rb") as f:
            if b"comment acq coloured cloud" not in f.read(4096):
                return None
        vertex = PlyData.read(str(path), mmap=True)["vertex"].data
        if len(vertex) == 0 or "scalar_time" not in (vertex.dtype.names or ()):
            return None
        return float(vertex["scalar_time"][0]), float(vertex["scalar_time"][-1])
    except (OSError, ValueError, KeyError, IndexError, struct.error, PlyParseError):
        return None  # not an acq cloud after all: not this drive's
