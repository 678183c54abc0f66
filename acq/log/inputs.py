"""The logs a command reads: files or folders of them, grouped by session, each session
read once.

Every command that reads logs resolves its LOG arguments here (:func:`sessions`, or
:func:`session_files` where it works on one session):

- a folder stands for its ``*.mcap`` files, in name order (not its sub-folders); a
  folder with a ``metadata.yaml`` is a ROS 2 bag: its storage files in the bag's order
  (:func:`acq.log.rosbag_source.bag_files`), one session;
- a file given twice (itself and in its folder) is read once;
- files are grouped by the session their writer names in the ``acq`` metadata record
  (``session``, :mod:`acq.log.writer`; for older logs the recorder's start, to the
  second, and host, or the ``<prefix>_<UTC start>_<NNN>.mcap`` name), in the order given;
- files of one session (a known one) that start with the same message hold the same
  recording: one is read. A repaired copy (``acq info --repair``, marked
  :data:`acq.log.repair.REPAIR_RECORD`; an older one by its name ``NAME.repaired.mcap``)
  given with its source is read in its source's place, the source instead when it has
  grown since it was copied (its writer went on); of other copies the first given.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

from mcap.records import Message, Metadata

from acq.errors import InputValueError
from acq.log.reader import LogError, LogReader, quiet
from acq.log.repair import REPAIR_RECORD
from acq.log.rosbag_source import bag_files

__all__ = ["Session", "log_files", "session_files", "session_stem", "sessions"]

log = logging.getLogger(__name__)

_PART = re.compile(r"^(.+_\d{8}T\d{6}Z)_\d{3,}$")  # the writer's <prefix>_<start>_<NNN>
_REPAIRED_SUFFIX = ".repaired"  # acq info --repair's default name: NAME.repaired.mcap


@dataclass
class Session:
    """The files of one recording session, in the order given. ``id``: the session's id
    (from its writer; None: a log that names none, grouped with the other such);
    ``label``: how a message names it; ``notes``: what resolving them chose (a repaired
    copy read in place of its source)."""

    id: str | None
    label: str
    files: list[Path] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def describe(self) -> str:
        """``session LABEL (FILE, FILE)``, for messages."""
        names = ", ".join(str(p) for p in self.files[:3])
        more = f" and {len(self.files) - 3} more" if len(self.files) > 3 else ""
        return f"session {self.label} ({names}{more})"


@dataclass(frozen=True)
class _Log:
    path: Path
    session: str | None
    label: str
    repair_of: tuple[str, int | None] | None  # a repaired copy's source: name, bytes then
    first_ns: int | None  # its first message's log time, as in the file (None: none)


def log_files(paths: Sequence[str | os.PathLike[str]], option: str = "LOG") -> list[Path]:
    """``paths`` with each folder replaced by its ``*.mcap`` files (sorted; a ROS 2 bag's
    in its order) and files given
    twice once. InputValueError (naming ``option``) for a folder without logs or a ROS 2
    bag that cannot be read; a missing file or one that is not MCAP is left to the reader."""
    out: list[Path] = []
    seen: set[tuple[int, int] | Path] = set()
    for given in paths:
        p = Path(given)
        if p.is_dir():
            found = bag_files(p) or sorted(f for f in p.glob("*.mcap") if f.is_file())
            if not found:
                raise InputValueError(f"{option} {p}: no .mcap files in this folder")
        else:
            found = [p]
        for f in found:
            try:
                st = f.stat()
                key: tuple[int, int] | Path = (st.st_dev, st.st_ino)
            except OSError:
                key = f.absolute()
            if key not in seen:
                seen.add(key)
                out.append(f)
    return out


def sessions(paths: Sequence[str | os.PathLike[str]], option: str = "LOG") -> list[Session]:
    """The sessions of ``paths`` (files or folders, see the module docstring), in the
    order their first file was given. A file that is missing or not MCAP is not a
    session: it goes first in the first one, for the command's reader to name it
    (:class:`acq.log.reader.LogError`) when it reads it, after the command's own checks.
    InputValueError as :func:`log_files`."""
    files = log_files(paths, option)
    logs: dict[Path, _Log] = {}
    for p in files:
        with contextlib.suppress(LogError):
            logs[p] = _glance(p)
    by_id: dict[str | None, Session] = {}
    for one in logs.values():
        by_id.setdefault(one.session, Session(one.session, one.label)).files.append(one.path)
    unreadable = [p for p in files if p not in logs]
    if unreadable:  # first, so that the reader names them before any long read
        first = next(iter(by_id.values()), None) or by_id.setdefault(
            None, Session(None, "without an id")
        )
        first.files[:0] = unreadable
    for s in by_id.values():
        _read_once(s, logs)
        for note in s.notes:
            log.warning("%s", note)
    return list(by_id.values())


def session_files(paths: Sequence[str | os.PathLike[str]], option: str = "LOG") -> list[Path]:
    """The files of the one session ``paths`` hold (:func:`sessions`). InputValueError
    naming each session and its files when they hold several: two drives have two
    clocks, and are never read as one."""
    found = sessions(paths, option)
    if len(found) > 1:
        listed = "; ".join(s.describe() for s in found)
        raise InputValueError(
            f"{option}: {len(found)} recording sessions given, {listed}; give one "
            "session's files (each drive has its own clock)"
        )
    return found[0].files if found else []


def session_stem(path: Path) -> str | None:
    """The session part of a writer's file name (``<prefix>_<UTC start>`` of
    ``<prefix>_<UTC start>_<NNN>.mcap``; None: not such a name): its parts share it."""
    m = _PART.match(path.name.removesuffix(".mcap"))
    return m.group(1) if m else None


def _glance(path: Path) -> _Log:
    """A log's session, repair mark and first message, from the metadata at its start
    (the writer puts it first; a closed file's from its index) and its first chunk; read
    once per process while the file keeps its size and time (the command line resolves a
    command's logs, and the library it calls again)."""
    try:
        st = path.stat()
    except OSError:
        return _read_glance(path)  # uncached: the reader names what is wrong with it
    return replace(_cached_glance(path.absolute(), st.st_size, st.st_mtime_ns), path=path)


@functools.lru_cache(maxsize=256)
def _cached_glance(path: Path, size: int, mtime_ns: int) -> _Log:
    """:func:`_read_glance` of ``path`` as it is at ``size`` bytes and ``mtime_ns``."""
    return _read_glance(path)


def _read_glance(path: Path) -> _Log:
    """:func:`_glance`, read from the file."""
    reader = LogReader(path, progress=False)
    metadata: dict[str, dict[str, str]] = {}
    first_ns = None
    records = reader.records()
    with quiet():  # its damage is for the command's reader to say
        try:
            for record in records:
                if isinstance(record, Metadata):
                    metadata.setdefault(record.name, dict(record.metadata))
                elif isinstance(record, Message):
                    first_ns = record.log_time
                    break
        finally:
            records.close()
    acq = metadata.get("acq", {})
    session = label = acq.get("session")
    if session is None and "started_utc" in acq:  # the recorder's, the same in every part
        label = f"started {acq['started_utc']}"
        session = f"{label} on {acq.get('host', '?')}"
    stem = path.name.removesuffix(".mcap").removesuffix(_REPAIRED_SUFFIX)
    if session is None and (m := _PART.match(stem)):
        session = label = m.group(1)
    mark = metadata.get(REPAIR_RECORD)
    repair_of: tuple[str, int | None] | None = None
    if mark is not None and "source" in mark:
        size = mark.get("source_bytes", "")
        repair_of = (mark["source"], int(size) if size.isdigit() else None)
    elif path.name.endswith(_REPAIRED_SUFFIX + ".mcap"):  # a copy made before the mark
        repair_of = (stem + ".mcap", None)
    return _Log(path, session, label or "without an id", repair_of, first_ns)


def _read_once(session: Session, logs: dict[Path, _Log]) -> None:
    """Files of ``session`` that start with the same message hold the same recording (a
    repaired copy and its source, or a copy): one of them is read, in the place of the
    first given, and a note says which."""
    if session.id is None:  # not acq's logs: nothing says they are one recording
        return
    groups: dict[int, list[Path]] = {}
    for p in session.files:
        first = logs[p].first_ns if p in logs else None
        if first is not None:
            groups.setdefault(first, []).append(p)
    for same in groups.values():
        if len(same) < 2:
            continue
        keep, note = _one_of(same, logs)
        at = session.files.index(same[0])
        session.files = [p for p in session.files if p not in same]
        session.files.insert(at, keep)
        session.notes.append(note)


def _one_of(same: list[Path], logs: dict[Path, _Log]) -> tuple[Path, str]:
    """Which of files holding the same recording to read, and the note saying so: a
    repaired copy (indexed) rather than its source, unless the source has grown since
    the copy (its writer went on); else the first given."""
    keep, why = same[0], "the same session and first message"
    for copy in same:
        mark = logs[copy].repair_of
        source = next((p for p in same if mark and p != copy and p.name == mark[0]), None)
        if mark is None or source is None:
            continue
        if mark[1] is not None and _size(source) > mark[1]:
            keep, why = source, "the log, grown since it was repaired"
        else:
            keep, why = copy, "its repaired copy, indexed"
        break
    dropped = ", ".join(str(p) for p in same if p != keep)
    return keep, f"{dropped} not read: the same recording as {keep} ({why})"


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0
