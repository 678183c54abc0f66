"""The kernel's PPS sources (``/sys/class/pps/ppsN``): the last assert and clear edges
of each pulse-per-second signal, as their sequence numbers and host UTC times. The
edges say whether a PPS arrives and when the host clock saw it; how close those times
are to whole seconds is the host clock's error against the PPS (when the PPS is on time).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from acq.time.absent import Absent

__all__ = ["PPS_ROOT", "PpsSource", "parse_edge", "read_pps"]

PPS_ROOT = Path("/sys/class/pps")


@dataclass(frozen=True)
class PpsSource:
    """One PPS source: ``name`` (``pps0``), ``assert_sequence`` and ``assert_s`` the last
    assert edge's count and host UTC s (0 before any), the same for the clear edge."""

    name: str
    assert_sequence: int
    assert_s: float
    clear_sequence: int
    clear_s: float

    @property
    def assert_error_s(self) -> float:
        """The last assert's host time minus the nearest whole second, s."""
        return self.assert_s - round(self.assert_s)


def parse_edge(text: str) -> tuple[float, int]:
    """A sysfs edge, ``<seconds>.<nanoseconds>#<sequence>``: (UTC s, sequence);
    ValueError for another text or a sequence outside 64 bits."""
    stamp, _, sequence = text.strip().partition("#")
    seconds, _, nanos = stamp.partition(".")
    count = int(sequence or 0)
    if len(text) > 64 or not 0 <= count < 2**64:
        raise ValueError(f"not a PPS edge: {text.strip()[:64]!r}")
    return int(seconds) + int(nanos or 0) * 1e-9, count


def read_pps(root: Path = PPS_ROOT) -> PpsSource | Absent:
    """The first PPS source under ``root`` (by name), or :class:`Absent` where there is
    none or it cannot be read."""
    try:
        names = sorted(p.name for p in root.iterdir() if p.name.startswith("pps"))
    except OSError:
        names = []
    if not names:
        return Absent("no PPS source")
    source = root / names[0]
    try:
        assert_s, assert_seq = parse_edge((source / "assert").read_text())
        clear_s, clear_seq = parse_edge((source / "clear").read_text())
    except (OSError, ValueError) as e:
        return Absent(f"{names[0]} unreadable: {e}")
    return PpsSource(names[0], assert_seq, assert_s, clear_seq, clear_s)
