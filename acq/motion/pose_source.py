"""Where colouring gets the rig's poses: any source with a trajectory's interface."""

from __future__ import annotations

from typing import Protocol

import numpy as np
import numpy.typing as npt

__all__ = ["PoseSource"]


class PoseSource(Protocol):
    """Vehicle -> world poses at host ns: a finished :class:`acq.motion.Trajectory` or
    the recorder's rolling one."""

    def covers(self, t_ns: npt.ArrayLike) -> np.ndarray: ...

    def pose_at(self, t_ns: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]: ...

    def transform(self, t_ns: npt.ArrayLike, points: npt.ArrayLike) -> np.ndarray: ...
