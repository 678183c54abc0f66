"""The errors of :mod:`acq.view` beyond acq's own (:mod:`acq.errors`)."""

from __future__ import annotations

from acq.errors import InputError

__all__ = ["FrameError"]


class FrameError(InputError):
    """A point or frame the server cannot answer for; ``status`` the HTTP status (404 a
    point or frame that is not there, 409 a cloud and log that do not belong together)."""

    def __init__(self, message: str, status: int = 404) -> None:
        super().__init__(message)
        self.status = status
