"""A command that writes files, stopped by a signal: the signal raises :class:`Stopped`
in the main thread, so that every writer's cleanup runs as for an error (its temporary
removed, the output as it was) and the command ends with one line and the shell's
status for the signal (128 + its number).

The signals are those that end `acq record` cleanly (SIGTERM, SIGHUP, SIGINT and every
other whose default action ends the process: :func:`acq.stop_signals.finishing_signals`);
SIGKILL cannot be caught: what it leaves is removed by the next run
(:func:`acq.atomic_write.remove_stale`).
"""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Iterator
from types import FrameType

from acq.stop_signals import finishing_signals, handling, signal_name

__all__ = ["Stopped", "shield_resource_tracker", "stopping"]


class Stopped(KeyboardInterrupt):
    """Raised by a signal within :func:`stopping`; a KeyboardInterrupt, so that what
    stops a pool of workers on Ctrl-C stops it here too. ``signum``: the signal."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum

    @property
    def name(self) -> str:
        """The signal's name: ``SIGTERM``."""
        return signal_name(self.signum)

    @property
    def exit_status(self) -> int:
        """128 + the signal's number, as a shell gives a process that signal ended."""
        return 128 + self.signum


@contextlib.contextmanager
def stopping() -> Iterator[None]:
    """Within, each of the finishing signals raises :class:`Stopped` (main thread only:
    Python runs signal handlers there); the handlers before are put back after."""

    def stop(signum: int, _frame: FrameType | None) -> None:
        raise Stopped(signum)

    with handling(stop):
        yield


def shield_resource_tracker() -> None:
    """Start multiprocessing's resource tracker (unless it runs) with the finishing signals
    blocked, so that a signal to the whole process group leaves it to the end: it ignores
    SIGINT and SIGTERM itself, but dies of a SIGHUP, and its successor then prints a
    traceback for each of the workers' resources while the command stops."""
    from multiprocessing import resource_tracker

    old = signal.pthread_sigmask(signal.SIG_BLOCK, finishing_signals())
    try:
        resource_tracker.ensure_running()
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)
