"""A clock source that is not there, and why: what the readers of :mod:`acq.time`
return instead of raising when a tool is not installed or a daemon does not answer."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["WHY_MAX_CHARS", "Absent"]

# a reason quotes what a tool printed: bounded, since the recorder writes it every second
WHY_MAX_CHARS = 200


@dataclass(frozen=True)
class Absent:
    """No reading from a clock source; ``why`` says why, in a few words (cut to
    :data:`WHY_MAX_CHARS`, an ellipsis marking the cut)."""

    why: str

    def __post_init__(self) -> None:
        if len(self.why) > WHY_MAX_CHARS:
            object.__setattr__(self, "why", self.why[: WHY_MAX_CHARS - 1] + "…")
