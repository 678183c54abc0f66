"""A log's times as UTC nanoseconds, whatever clock the log was written on."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from acq.errors import InputValueError
from acq.time.utc import utc_ns

__all__ = ["LogClock", "log_is_utc"]


def log_is_utc(metadata: Mapping[str, Mapping[str, str]]) -> bool:
    """Whether a log's ``log_time`` and stamps are UTC already: its ``acq`` metadata's
    ``clock`` line names UTC and not the host monotonic clock (logs that say
    ``CLOCK_MONOTONIC``, or say nothing, are host monotonic)."""
    text = metadata.get("acq", {}).get("clock", "")
    return "UTC" in text and "MONOTONIC" not in text.upper()


class LogClock:
    """Maps a log's times (int ns) to UTC ns: through the log's (monotonic, realtime)
    pairs (``/acq/clock``) for a host-monotonic log, unchanged for a UTC one."""

    def __init__(self, utc: bool, pairs: np.ndarray) -> None:
        self.utc = utc
        self.pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        if not utc and self.pairs.shape[0] == 0:
            raise InputValueError(
                "the log's times are host monotonic and it has no /acq/clock pairs: "
                "they cannot be mapped to UTC"
            )
        self._base = 0
        if not utc:  # one pair: a constant offset, the common case
            self._base = int(self.pairs[0, 1] - self.pairs[0, 0])

    def to_utc(self, t_ns: int) -> int:
        """UTC ns of the log time ``t_ns``."""
        if self.utc:
            return int(t_ns)
        if self.pairs.shape[0] == 1:
            return int(t_ns) + self._base
        return int(utc_ns(np.array([t_ns], np.int64), self.pairs)[0])
