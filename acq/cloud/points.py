"""Coloured points held in memory (:class:`Cloud`), as the preview draws them.

Times are host ``CLOCK_MONOTONIC`` ns (int64) unless a name ends in ``_s``; positions
are metres in the world frame; colours RGB uint8.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Cloud:
    """Coloured points, one per laser return, in scan order.

    Per point: ``xyz`` (P,3) float64 m in the world frame; ``rgb`` (P,3) uint8 (zero
    where not coloured); ``coloured`` (P,) bool; ``time_ns`` (P,) int64 host monotonic
    ns of the measurement; ``scan`` (P,) uint32 index of its scan in the log; ``step``
    (P,) uint32 its index within the scan; ``intensity`` (P,) float32 device units;
    ``dt_s`` (P,) float32 its time minus its frame's (NaN where not coloured);
    ``camera`` (P,) uint8 the index in ``camera_names`` of the camera it was coloured
    from (255 none); ``frame`` (P,) int32 the index of that frame among the camera's
    frames in the session, in time order (-1 none).
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
    camera: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint8))
    frame: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    camera_names: tuple[str, ...] = ()
    frames: int = 0
    frames_used: int = 0
    frames_failed: int = 0

    @property
    def size(self) -> int:
        return int(self.time_ns.size)

    @property
    def coloured_share(self) -> float:
        return float(self.coloured.mean()) if self.size else 0.0
