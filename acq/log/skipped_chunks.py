"""The corrupt chunks a pass over a log skipped (:class:`acq.log.reader.LogReader`), and
the one warning line per file that names their times and the messages lost, said once per
process (a command that reads a file several times says it once), and the same for the
channels whose messages did not decode (:func:`unreported_topics`) and for a file that was
not closed (:func:`unreported_cut`); :func:`quiet` leaves
that to a caller that reports the damage itself (``acq info``)."""

from __future__ import annotations

import contextlib
import contextvars
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "Skipped",
    "describe",
    "describe_cut",
    "quiet",
    "unreported",
    "unreported_cut",
    "unreported_note",
    "unreported_topics",
]


@dataclass
class Skipped:
    """A corrupt chunk skipped: its record's byte offset, its messages' first and last log
    times (ns; None: unknown) and how many there were (None: unknown)."""

    at: int
    start_ns: int | None = None
    end_ns: int | None = None
    messages: int | None = None


_REPORTED: set[tuple[str, int]] = set()  # (file, chunk offset) already reported here
_REPORTED_TOPICS: set[tuple[str, str]] = set()  # (file, topic) undecodable, reported here
_REPORTED_CUT: set[str] = set()  # files not closed, reported here
_REPORTED_NOTES: set[tuple[str, str]] = set()  # (file, kind of note) said here
_REPORTED_LOCK = threading.Lock()
_QUIET: contextvars.ContextVar[bool] = contextvars.ContextVar("acq_log_quiet", default=False)


@contextlib.contextmanager
def quiet() -> Iterator[None]:
    """Within it, the logs read log no warning for their corrupt chunks: for a caller that
    reports :meth:`acq.log.reader.LogReader.problem` itself."""
    token = _QUIET.set(True)
    try:
        yield
    finally:
        _QUIET.reset(token)


def unreported(path: Path, skipped: list[Skipped]) -> list[Skipped]:
    """The chunks of ``skipped`` this process has not reported yet, now marked reported;
    none within :func:`quiet`."""
    if not skipped or _QUIET.get():
        return []
    key = str(path.resolve())
    with _REPORTED_LOCK:
        new = [s for s in skipped if (key, s.at) not in _REPORTED]
        _REPORTED.update((key, s.at) for s in new)
    return new


def unreported_topics(path: Path, counts: dict[str, int]) -> dict[str, int]:
    """The topics of ``counts`` (topic -> messages not decoded) this process has not
    reported for ``path`` yet, now marked reported; none within :func:`quiet`."""
    if not counts or _QUIET.get():
        return {}
    key = str(path.resolve())
    with _REPORTED_LOCK:
        new = {t: n for t, n in counts.items() if n and (key, t) not in _REPORTED_TOPICS}
        _REPORTED_TOPICS.update((key, t) for t in new)
    return new


def unreported_cut(path: Path) -> bool:
    """Whether this process has not yet said that ``path`` was not closed, now marked said;
    False within :func:`quiet`."""
    if _QUIET.get():
        return False
    key = str(path.resolve())
    with _REPORTED_LOCK:
        new = key not in _REPORTED_CUT
        _REPORTED_CUT.add(key)
    return new


def unreported_note(path: Path, kind: str) -> bool:
    """Whether this process has not yet said the note ``kind`` (e.g. ``"clock"``) about
    ``path``, now marked said; False within :func:`quiet`."""
    if _QUIET.get():
        return False
    key = (str(path.resolve()), kind)
    with _REPORTED_LOCK:
        new = key not in _REPORTED_NOTES
        _REPORTED_NOTES.add(key)
    return new


def describe(skipped: list[Skipped], start_ns: int | None) -> str:
    """``N corrupt chunks skipped (WHERE, M messages lost)``: where as seconds from the
    file's first log time ``start_ns`` (ns) when known, else as byte offsets."""
    where = []
    for s in skipped[:3]:
        if start_ns is not None and s.start_ns is not None and s.end_ns is not None:
            where.append(
                f"{(s.start_ns - start_ns) * 1e-9:.1f}..{(s.end_ns - start_ns) * 1e-9:.1f} s"
            )
        else:
            where.append(f"at byte {s.at}")
    text = ", ".join(where) + (f" and {len(skipped) - 3} more" if len(skipped) > 3 else "")
    if any(w.endswith(" s") for w in where):
        text += " into the file"
    known = [s.messages for s in skipped if s.messages is not None]
    if known:
        least = "" if len(known) == len(skipped) else "at least "
        text += f", {least}{sum(known)} messages lost"
    chunks = "chunk" if len(skipped) == 1 else "chunks"
    return f"{len(skipped)} corrupt {chunks} skipped ({text})"


def describe_cut(
    writing: bool,
    footer_at: int | None,
    stop: str | None,
    start_ns: int | None,
    end_ns: int | None,
    utc_offset_ns: int,
    bytes_read: int,
) -> str:
    """What a file that is not closed is and what of it was read: being written (its
    recorder alive) or cut, and the span of log time (``start_ns``..``end_ns``, the file's
    own log times less ``utc_offset_ns``: as the reader's messages give them)."""
    if writing:
        how = "is being written (its recorder is running)"
    elif footer_at is not None:
        how = f"was not closed (a footer at byte {footer_at} but {stop})"
    else:
        how = "was not closed (its writer stopped)"
    if start_ns is None or end_ns is None:
        return f"{how}: no message in the {bytes_read} bytes read"
    first, last = (start_ns - utc_offset_ns) * 1e-9, (end_ns - utc_offset_ns) * 1e-9
    return f"{how}: read up to {last - first:.1f} s of it (log time {first:.3f}..{last:.3f} s)"
