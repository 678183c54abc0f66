"""``/live/swath``: the coloured scans of the last seconds as one point cloud, so the street
builds up on a live client's screen as the car drives.

A :class:`Swath` keeps each coloured scan's coloured points (placed in the trajectory's
world frame, or in the laser frame when the rig has no trajectory) for ``span_s``, and
makes one ``foxglove.PointCloud`` of them at most every ``period_s``, decimated to at
most ``max_points`` (every k-th point: the newest scans as dense as the oldest). Points
of another frame than the newest scan's are dropped (the frame changes when the rig's
poses start or stop covering the scans). Times host ns (the log's clock).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from acq.log.cloud_message import CLOUD_DTYPE, cloud_of_points, points

__all__ = ["MAX_POINTS", "PERIOD_S", "SPAN_S", "Swath"]

POINT_BYTES = CLOUD_DTYPE.itemsize
SPAN_S = 30.0  # s of scans kept (acq record --live-swath-s)
PERIOD_S = 0.5  # s between two swaths (2 Hz)
MAX_POINTS = 300_000  # points in one swath at most


@dataclass(frozen=True)
class _Part:
    stamp_ns: int
    points: np.ndarray  # (N,16) uint8: the points of cloud_message.CLOUD_DTYPE, as sent


class Swath:
    """The last ``span_s`` of coloured points, as a cloud every ``period_s``."""

    def __init__(
        self, span_s: float = SPAN_S, period_s: float = PERIOD_S, max_points: int = MAX_POINTS
    ) -> None:
        if not span_s > 0 or not period_s > 0 or max_points < 1:
            raise ValueError("span_s > 0, period_s > 0 and max_points >= 1 expected")
        self.span_ns = round(span_s * 1e9)
        self.period_ns = round(period_s * 1e9)
        self.max_points = max_points
        self.frame_id = ""
        self._parts: deque[_Part] = deque()
        self._points = 0
        self._last_ns: int | None = None  # when the last swath was made
        self.made = 0

    @property
    def points(self) -> int:
        """Points held (before decimation)."""
        return self._points

    def add(self, stamp_ns: int, xyz: np.ndarray, rgb: np.ndarray, frame_id: str) -> None:
        """One scan's points (N,3) m in ``frame_id`` with their (N,3) colours."""
        if frame_id != self.frame_id:
            self._parts.clear()
            self._points = 0
            self.frame_id = frame_id
        ok = np.isfinite(xyz).all(axis=1)
        part = _Part(stamp_ns, points(xyz[ok], rgb[ok]).view(np.uint8).reshape(-1, POINT_BYTES))
        self._parts.append(part)
        self._points += part.points.shape[0]
        while self._parts and self._parts[0].stamp_ns < stamp_ns - self.span_ns:
            self._points -= self._parts.popleft().points.shape[0]

    def due(self, now_ns: int) -> bool:
        """Whether a swath is due at ``now_ns`` (``period_s`` after the last made)."""
        return bool(self._parts) and (
            self._last_ns is None or now_ns - self._last_ns >= self.period_ns
        )

    def cloud(self, now_ns: int, stamp_ns: int) -> bytes:
        """The swath as ``foxglove.PointCloud`` bytes stamped ``stamp_ns`` (the log's
        time), decimated to at most ``max_points``; made at ``now_ns``."""
        self._last_ns = now_ns
        self.made += 1
        step = -(-self._points // self.max_points) if self._points else 1
        # every step-th point of the whole, each part's share taken before joining them
        picked, start = [], 0
        for part in self._parts:
            picked.append(part.points[(-start) % step :: step])
            start += part.points.shape[0]
        held = np.concatenate(picked) if picked else np.zeros((0, POINT_BYTES), np.uint8)
        return cloud_of_points(held, self.frame_id, stamp_ns)
