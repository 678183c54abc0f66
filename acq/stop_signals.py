"""The signals that end `acq record`, each finishing the file.

Every signal whose default action ends the process finishes the file as SIGTERM does:
the recorder stops, closes the file (footer and summary written) and exits as after
``--duration``. SIGHUP is one of them, not ignored: a terminal that goes away (an ssh
link that drops) leaves nobody to watch the recording or end it with Ctrl-C and its log
lines nowhere to go, so the recording ends there with its file whole rather than run on
unattended; to record through a dropped link run the systemd unit, or ``nohup``, ``tmux``.
SIGUSR1, SIGUSR2, SIGALRM, SIGQUIT and the real-time signals end it the same way.

Left to their default action:

- SIGKILL and SIGSTOP, which no process can catch (after a SIGKILL the file is readable
  up to its last fsynced second; ``acq info --repair`` indexes it);
- the faults SIGSEGV, SIGBUS, SIGILL and SIGFPE: the process's own bad access, into
  which a handler would return again and again;
- SIGABRT: systemd's watchdog sends it to a writer that stopped pinging, which could not
  run a handler, and ``PYTHONFAULTHANDLER`` then writes every thread's stack;
- SIGPIPE and SIGXFSZ, which Python ignores: the write fails instead, and the recorder
  handles that as a failed write.
"""

from __future__ import annotations

import contextlib
import logging
import signal
from collections.abc import Callable, Iterator
from types import FrameType

__all__ = ["LEFT_TO_DEFAULT", "finishing", "finishing_signals", "handling", "signal_name"]

log = logging.getLogger("acq.record")

# default action: stop, continue, or nothing: no end to finish
_NOT_ENDING = ("SIGCHLD", "SIGCONT", "SIGSTOP", "SIGTSTP", "SIGTTIN", "SIGTTOU", "SIGURG",
               "SIGWINCH")  # fmt: skip
LEFT_TO_DEFAULT = ("SIGKILL", "SIGSEGV", "SIGBUS", "SIGILL", "SIGFPE", "SIGABRT", "SIGPIPE",
                   "SIGXFSZ")  # fmt: skip
"""Ending signals a recording leaves to their default action (see the module's text)."""


def finishing_signals() -> list[int]:
    """The numbers of the signals that finish the file: every valid one of this system but
    those whose default does not end the process and :data:`LEFT_TO_DEFAULT`."""
    skip = {getattr(signal, name) for name in (*_NOT_ENDING, *LEFT_TO_DEFAULT)
            if hasattr(signal, name)}  # fmt: skip
    return sorted(int(s) for s in signal.valid_signals() if s not in skip)


def signal_name(signum: int) -> str:
    """``SIGHUP`` for 1; a real-time signal as ``SIGRTMIN+N``."""
    try:
        return signal.Signals(signum).name
    except ValueError:
        rtmin = getattr(signal, "SIGRTMIN", None)
        return f"SIGRTMIN+{signum - rtmin}" if rtmin is not None else f"signal {signum}"


@contextlib.contextmanager
def finishing(stop: Callable[[], None]) -> Iterator[list[int]]:
    """Within, each of :func:`finishing_signals` logs its name and calls ``stop``; the
    handlers before are put back after. Yields the signals handled (main thread only:
    Python runs signal handlers there)."""

    def finish(signum: int, _frame: FrameType | None) -> None:
        log.info("%s: finishing the file", signal_name(signum))
        stop()

    with handling(finish) as handled:
        yield handled


@contextlib.contextmanager
def handling(handler: Callable[[int, FrameType | None], None]) -> Iterator[list[int]]:
    """Within, ``handler`` handles each of :func:`finishing_signals`; the handlers before
    are put back after. Yields the signals handled (main thread only)."""
    old: dict[int, object] = {}
    try:
        for s in finishing_signals():
            try:
                old[s] = signal.signal(s, handler)
            except (OSError, ValueError):  # one the C library keeps for itself
                continue
        yield sorted(old)
    finally:
        for s, h in old.items():
            signal.signal(s, h)  # type: ignore[arg-type]
