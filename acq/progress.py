"""Progress bars on stderr for long work, in the work's own units, with a rate and an
estimated time left (tqdm), quiet when stderr is not a terminal unless asked.

The command says once whether bars are shown (:func:`enable`); the library code doing
long work opens a bar around it (:func:`bar`) and reports what it has done
(:func:`advance`) without knowing whether anyone shows it. Reading logs reports bytes:
every command that reads logs shows that phase in a bar in bytes (:func:`reading`).
"""

from __future__ import annotations

import os
import sys
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any

__all__ = ["advance", "bar", "enable", "reading", "wanted"]

_lock = threading.Lock()
_enabled = False  # what the command said (enable)
_bars: dict[str, Any] = {}  # unit -> the open bar counting it (at most one per unit)


def wanted(forced: bool = False) -> bool:
    """Whether to show bars: ``forced`` (``--progress``), or stderr is a terminal."""
    return forced or sys.stderr.isatty()


def enable(on: bool) -> None:
    """Whether the bars opened from now on are shown (the command's choice)."""
    global _enabled
    _enabled = on


@contextmanager
def bar(
    total: float, unit: str, desc: str, shown: bool | None = None, scale: float | None = None
) -> Iterator[None]:
    """A bar of ``total`` ``unit`` (``B`` for bytes, shown as MB) while the block runs,
    shown as the command said (:func:`enable`) unless ``shown`` says; what
    :func:`advance` reports in ``unit`` moves it, at most twice a second. ``scale``: the
    counts are shown times it (e.g. whole ms counted, 0.001: shown as seconds)."""
    from tqdm import tqdm

    shown = _enabled if shown is None else shown
    with _lock:
        if unit in _bars or not shown:  # an outer bar counts this already, or none wanted
            opened = None
        else:
            opened = _bars[unit] = tqdm(
                total=total, unit=unit, desc=desc, file=sys.stderr, mininterval=0.5,
                unit_scale=scale or unit == "B", unit_divisor=1000, dynamic_ncols=True,
                leave=True,
            )  # fmt: skip
    try:
        yield
    finally:
        if opened is not None:
            with _lock:
                del _bars[unit]
            opened.close()  # again if it filled: tqdm closes once


def reading(paths: Sequence[str | os.PathLike[str]], shown: bool | None = None) -> Any:
    """A bar in bytes over reading the files ``paths`` (those that exist)."""
    total = sum(os.path.getsize(p) for p in paths if os.path.isfile(p))
    return bar(total, "B", "reading", shown)


def advance(n: float, unit: str = "B") -> None:
    """``n`` more ``unit`` of work done (nothing when no bar counts ``unit``)."""
    if not _bars:
        return
    with _lock:
        b = _bars.get(unit)
        if b is not None:
            b.update(n)
            if b.total and b.n >= b.total:  # done: the line ends before what is printed next
                b.close()
