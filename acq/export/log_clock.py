"""A log's times as UTC nanoseconds, whatever clock the log was written on."""

from __future__ import annotations

import numpy as np

from acq.errors import InputValueError
from acq.log.timebase import TimeBase
from acq.time.utc import utc_ns

__all__ = ["LogClock"]


class LogClock:
    """Maps host monotonic times (int ns, as :class:`acq.log.LogReader` gives every time)
    to UTC ns: through the session's offset for a UTC log (the very times in the file),
    through its (monotonic, realtime) pairs (``/acq/clock``) for a host-monotonic one."""

    def __init__(self, time_base: TimeBase, pairs: np.ndarray) -> None:
        self.time_base = time_base
        self.utc = time_base.utc
        self.pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        if not self.utc and self.pairs.shape[0] == 0:
            raise InputValueError(
                "the log's times are host monotonic and it has no /acq/clock pairs: "
                "they cannot be mapped to UTC"
            )
        self._base = 0
        if not self.utc:  # one pair: a constant offset, the common case
            self._base = int(self.pairs[0, 1] - self.pairs[0, 0])

    def to_utc(self, t_ns: int) -> int:
        """UTC ns of the host monotonic time ``t_ns``."""
        if self.utc:
            return self.time_base.to_log(int(t_ns))
        if self.pairs.shape[0] == 1:
            return int(t_ns) + self._base
        return int(utc_ns(np.array([t_ns], np.int64), self.pairs)[0])
