"""Where a log time lies in a session's files: a file's first log time, and a time named
as a user finds it again ("log time T s, S s into FILE")."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from mcap.records import Chunk, Message

from acq.log.reader import LogError, LogReader
from acq.log.timebase import TimeBase

__all__ = ["first_log_time", "locate"]


def first_log_time(path: str | os.PathLike[str]) -> int | None:
    """The log time of a log's first message, host monotonic ns as the reader gives it
    (None: it has none readable): from the summary's statistics when the file is closed,
    else its first readable message."""
    reader = LogReader(path)
    with reader.path.open("rb") as f:
        summary = reader._closed_summary(f)
    if reader._start_ns is not None and summary is not None:
        return _time_base(path).to_host(reader._start_ns)
    for _, _, message in reader.messages():  # the pass ends here, its file closed
        return message.log_time
    return None


def locate(paths: Sequence[str | os.PathLike[str]], log_time_ns: int) -> str:
    """Where a log time lies in a log or in the files of a session (in their order):
    "log time T s, S s into FILE" (T, S seconds)."""
    files = [Path(p) for p in paths]
    found, start = files[0] if files else None, None
    for path in files:
        try:
            first = first_log_time(path)
        except LogError:
            continue
        if first is not None and (first <= log_time_ns or start is None):
            found, start = path, first
        if first is not None and first > log_time_ns:
            break
    where = f"log time {log_time_ns * 1e-9:.3f} s"
    if found is None:
        return where
    if start is None:
        return f"{where} in {found}"
    return f"{where}, {(log_time_ns - start) * 1e-9:.2f} s into {found}"


def _time_base(path: str | os.PathLike[str]) -> TimeBase:
    """A log's clock (:attr:`LogReader.time_base`), from the records before its first
    message."""
    reader = LogReader(path, progress=False)
    records = reader.records()
    try:
        for record in records:
            if isinstance(record, Message | Chunk):
                break
    finally:
        records.close()
    return reader.time_base
