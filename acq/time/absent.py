"""A clock source that is not there, and why: what the readers of :mod:`acq.time`
return instead of raising when a tool is not installed or a daemon does not answer."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Absent"]


@dataclass(frozen=True)
class Absent:
    """No reading from a clock source; ``why`` says why, in a few words."""

    why: str
