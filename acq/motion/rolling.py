"""The live pose source (:class:`RollingTrajectory`): the vehicle topics' messages as the
recorder logs them go in on one thread; the trajectory of the last ``window_s`` comes out
on another, chosen and built as offline (:func:`acq.motion.pose_source.trajectory_from_vehicle`).

The world frame holds still between builds: dead reckoning starts each build from the
previous build's pose at the window's first sample, and GNSS keeps the ENU origin of the
first build's first fix. When the fixes stop for longer than ``gnss_outage_s`` (a
tunnel), dead reckoning goes on from the last fused pose at the last fix, in the GNSS
frame; when 5 have come back, the fusion starts at their return (a fit to the few fixes
at one end of the window would extrapolate their errors over the rest of it). The
frame's kind changes once, when GNSS starts to count (``"odometry"`` until 5 usable fixes
have come, ``"enu"`` or the CRS after): the trajectory's ``frame`` says which. Times are
host monotonic ns unless a name ends in ``_s``.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np

from acq.errors import AcqError
from acq.geometry.transforms import Rigid
from acq.log.vehicle_log import Fixes, Odometry, VehicleLog, VehicleReader
from acq.motion.pose_source import MIN_FIXES, Chosen, trajectory_from_vehicle
from acq.motion.trajectory import Trajectory

__all__ = ["RollingTrajectory"]

_TRIM_EVERY = 1024  # rows added between two trims when no build trims
_Table = TypeVar("_Table", Odometry, Fixes)


class RollingTrajectory:
    """A trajectory rebuilt from the vehicle messages that have arrived (thread-safe:
    :meth:`add` on one thread, :meth:`current` on another).

    ``window_s``: the span of data each build covers (s; older rows are dropped, so a
    build's cost and the memory stay flat over an hour's drive); ``rebuild_s``: the least
    time between two builds (s); ``crs``: GNSS into this CRS instead of ENU;
    ``gnss_outage_s``: fixes this much older than the newest odometry are not fused
    (module docstring); ``clock``: seconds for ``rebuild_s`` (time.monotonic)."""

    TOPICS = VehicleReader.TOPICS

    def __init__(
        self,
        *,
        window_s: float = 120.0,
        rebuild_s: float = 0.2,
        crs: str | None = None,
        gnss_outage_s: float = 2.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not window_s > 0 or not rebuild_s >= 0:
            raise ValueError("window_s must be > 0 and rebuild_s >= 0")
        self.window_s = window_s
        self.rebuild_s = rebuild_s
        self.crs = crs
        self.gnss_outage_s = gnss_outage_s
        self._clock = clock
        self._lock = threading.Lock()  # the rows, _latest, _generation
        self._build_lock = threading.Lock()  # one build at a time, and what it made
        self._rows = VehicleReader()
        self._latest: int | None = None
        self._generation = 0  # rows added so far
        self._since_trim = 0
        self._built_generation = 0
        self._built_at = -float("inf")
        self._chosen: Chosen | None = None
        self._enu_origin: tuple[float, float, float] | None = None
        self._error: str | None = None
        self.builds = 0

    def add(self, topic: str, msg: Any) -> None:
        """One decoded message of a vehicle topic (:attr:`TOPICS`, decoded as
        :class:`acq.log.vehicle_log.VehicleReader` takes them; others are ignored)."""
        if topic not in self.TOPICS:
            return
        with self._lock:
            t = self._rows.add(topic, msg)
            if t is None:
                return
            self._latest = t if self._latest is None else max(self._latest, t)
            self._generation += 1
            self._since_trim += 1
            if self._since_trim >= _TRIM_EVERY:
                self._trim()

    def latest_ns(self) -> int | None:
        """Host ns of the newest vehicle sample that has arrived (None: none yet)."""
        with self._lock:
            return self._latest

    def kept_rows(self) -> int:
        """Odometry rows, fixes and poses held (bounded by ``window_s``)."""
        with self._lock:
            r = self._rows
            return len(r.odometry) + len(r.fixes) + len(r.poses)

    def chosen(self) -> Chosen | None:
        """The last build's choice: trajectory, one-line description, notes (None
        before the first build)."""
        with self._build_lock:
            return self._chosen

    @property
    def error(self) -> str | None:
        """Why the last build failed (its data unusable: the previous trajectory is
        kept), or None."""
        with self._build_lock:
            return self._error

    def current(self) -> Trajectory | None:
        """The trajectory of the last ``window_s`` of data (None: none can be made yet),
        rebuilt when new data came and ``rebuild_s`` has passed since the last build."""
        with self._build_lock:
            now = self._clock()
            if now - self._built_at < self.rebuild_s:
                return self._trajectory()
            with self._lock:
                if self._generation == self._built_generation:
                    return self._trajectory()
                generation = self._generation
                self._trim()
                snapshot = VehicleReader()
                snapshot.odometry = list(self._rows.odometry)
                snapshot.fixes = list(self._rows.fixes)
                snapshot.poses = dict(self._rows.poses)
            self._built_at, self._built_generation = now, generation
            vehicle = _gnss_span(snapshot.result(()), self.gnss_outage_s)
            previous = self._trajectory()
            start = None
            if previous is not None and len(vehicle.odometry):
                start = _pose_near(previous, int(vehicle.odometry.t_ns[0]))
            try:
                chosen = trajectory_from_vehicle(
                    vehicle, self.crs, enu_origin=self._enu_origin, start=start
                )
            except (AcqError, ValueError) as e:
                self._error = str(e)
                return previous
            if chosen.kind == "odometry" and previous is not None and previous.frame != "odometry":
                chosen = _continued(chosen, previous)
            self._error = None
            self.builds += 1
            self._chosen = chosen
            traj = chosen.trajectory
            if traj is not None and traj.frame == "enu" and self._enu_origin is None:
                self._enu_origin = traj.origin
            return traj

    def _trajectory(self) -> Trajectory | None:
        return None if self._chosen is None else self._chosen.trajectory

    def _trim(self) -> None:
        """Drop the rows older than ``window_s`` before the newest (holding _lock)."""
        self._since_trim = 0
        if self._latest is None:
            return
        cut = self._latest - round(self.window_s * 1e9)
        r = self._rows
        r.odometry = [row for row in r.odometry if row[0] >= cut]
        r.fixes = [row for row in r.fixes if row[0] >= cut]
        r.poses = {t: row for t, row in r.poses.items() if t >= cut}


def _gnss_span(vehicle: VehicleLog, outage_s: float) -> VehicleLog:
    """``vehicle`` with the odometry limited to the span its fixes cover: when the last
    fix is more than ``outage_s`` older than the newest odometry, no fixes and the
    odometry from the last fix on; when the fixes came after a silence longer than
    ``outage_s`` (from the odometry's start or between two fixes), the fixes and
    odometry from their return on, once :data:`MIN_FIXES` have come (no fixes before)."""
    odo, fixes = vehicle.odometry, vehicle.fixes
    if len(odo) < 2 or not len(fixes):
        return vehicle
    good = fixes.t_ns[(fixes.quality > 0) & np.isfinite(fixes.lat) & np.isfinite(fixes.lon)]
    if not good.size:
        return vehicle
    outage_ns = outage_s * 1e9
    if odo.t_ns[-1] - good[-1] > outage_ns:
        first, fixes = int(good[-1]), _rows(fixes, np.zeros(len(fixes), bool))
    else:  # a silence since the odometry's first sample or between two fixes
        silences = np.flatnonzero(np.diff(np.concatenate([odo.t_ns[:1], good])) > outage_ns)
        if not silences.size:
            return vehicle
        first = int(good[silences[-1]])
        if good.size - silences[-1] < MIN_FIXES:  # too few yet: dead reckoning goes on
            return dataclasses.replace(vehicle, fixes=_rows(fixes, np.zeros(len(fixes), bool)))
        fixes = _rows(fixes, fixes.t_ns >= first)
    keep = odo.t_ns >= first
    keep[-2:] = True  # a span just begun: the last two samples
    return dataclasses.replace(vehicle, odometry=_rows(odo, keep), fixes=fixes)


def _rows(table: _Table, keep: np.ndarray) -> _Table:
    """The rows ``keep`` (bool) of a dataclass of row-aligned arrays."""
    arrays = {f.name: getattr(table, f.name)[keep] for f in dataclasses.fields(table)}
    return dataclasses.replace(table, **arrays)


def _pose_near(traj: Trajectory, t_ns: int) -> Rigid:
    """The pose at ``t_ns``, or at the nearest end when outside (a gap in the odometry
    longer than the window: the vehicle is taken to have stood still)."""
    t = np.array([min(max(t_ns, traj.start_ns), traj.end_ns)], dtype=np.int64)
    if not traj.covers(t)[0]:  # inside a flagged gap: its first end
        i = int(np.searchsorted(traj.t_ns, t[0], side="right")) - 1
        t[0] = traj.t_ns[i]
    R, p = traj.pose_at(t)
    return Rigid(R[0], p[0])


def _continued(chosen: Chosen, previous: Trajectory) -> Chosen:
    """Dead reckoning started from a pose of ``previous`` (in a GNSS frame), labelled
    with that frame."""
    traj = chosen.trajectory
    assert traj is not None
    moved = Trajectory(
        traj.t_ns, traj.rotation, traj.translation, previous.frame, previous.origin,
        traj.max_gap_s, traj.margin_s,
    )  # fmt: skip
    description = f"{chosen.description}, continued in the {previous.frame} frame of GNSS"
    return dataclasses.replace(chosen, trajectory=moved, description=description)
