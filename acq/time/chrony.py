"""chrony's tracking report, as ``chronyc -c tracking`` gives it: which reference the
host follows, how far the host clock was from it, and whether chrony calls it
synchronised. Read through ``chronyc`` with a short timeout; a missing ``chronyc`` or a
``chronyd`` that does not answer is :class:`acq.time.absent.Absent`, not an error.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass

from acq.time.absent import Absent
from acq.time.tool_answer import ask_tool

__all__ = ["ChronyTracking", "parse_tracking", "read_chrony_tracking"]

TIMEOUT_S = 0.5
_FLOATS = (
    "ref time", "system offset", "last offset", "rms offset", "frequency",
    "residual frequency", "skew", "root delay", "root dispersion", "update interval",
)  # fmt: skip
NAME_MAX_CHARS = 255  # a host name's longest (RFC 1035), an address or four letters


@dataclass(frozen=True)
class ChronyTracking:
    """One tracking report. ``reference_id`` the 32-bit reference ID (its four ASCII
    letters for a reference clock), ``reference_name`` its name or address;
    ``system_offset_s`` the correction chrony still applies (positive: the host clock is
    behind), ``last_offset_s`` the host clock minus the reference at the last update,
    ``rms_offset_s`` their long-term mean, s; ``frequency_ppm`` the host clock's rate
    error chrony corrects (positive: fast), ``residual_frequency_ppm`` and ``skew_ppm``
    its residual and error bound; ``root_delay_s`` and ``root_dispersion_s`` to the
    primary reference; ``update_interval_s`` between updates; ``leap_status`` "Normal",
    "Insert second", "Delete second" or "Not synchronised"; ``ref_time_s`` UTC s of
    the last update."""

    reference_id: int
    reference_name: str
    stratum: int
    ref_time_s: float
    system_offset_s: float
    last_offset_s: float
    rms_offset_s: float
    frequency_ppm: float
    residual_frequency_ppm: float
    skew_ppm: float
    root_delay_s: float
    root_dispersion_s: float
    update_interval_s: float
    leap_status: str

    @property
    def synchronised(self) -> bool:
        """chrony follows a reference (its leap status is not "Not synchronised")."""
        return self.leap_status != "Not synchronised" and self.reference_id != 0


def parse_tracking(line: str) -> ChronyTracking:
    """A ``chronyc -c tracking`` line (14 comma-separated fields); ValueError naming the
    field when it is not one, or holds a value a tracking report cannot have (a reference
    ID beyond 32 bits, a stratum outside 0..255, a name longer than a host name)."""
    f = line.strip().split(",")
    if len(f) != 14:
        raise ValueError(f"chronyc tracking: {len(f)} fields, expected 14: {line.strip()[:80]!r}")

    def number(k: int) -> float:
        return _number(_FLOATS[k - 3], f[k])

    return ChronyTracking(
        reference_id=_integer("reference ID", f[0], 16, 0xFFFFFFFF),
        reference_name=_text("reference name", f[1]),
        stratum=_integer("stratum", f[2], 10, 255),
        ref_time_s=number(3),
        system_offset_s=number(4),
        last_offset_s=number(5),
        rms_offset_s=number(6),
        frequency_ppm=number(7),
        residual_frequency_ppm=number(8),
        skew_ppm=number(9),
        root_delay_s=number(10),
        root_dispersion_s=number(11),
        update_interval_s=number(12),
        leap_status=_text("leap status", f[13]),
    )


def _shown(text: str) -> str:
    """A field as a reason quotes it: its start, when long."""
    return repr(text if len(text) <= 24 else text[:20] + "...")


def _integer(name: str, text: str, base: int, high: int) -> int:
    """A field that is an integer in 0..``high``; ValueError naming it else."""
    try:
        value = int(text, base) if len(text) <= 24 else -1
    except ValueError:
        value = -1
    if not 0 <= value <= high:
        raise ValueError(f"chronyc tracking: {name} {_shown(text)} is not in 0..{high:#x}")
    return value


def _number(name: str, text: str) -> float:
    """A field that is a decimal number; ValueError naming it else."""
    try:
        if len(text) <= 64:
            return float(text)
    except ValueError:
        pass
    raise ValueError(f"chronyc tracking: {name} {_shown(text)} is not a number")


def _text(name: str, text: str) -> str:
    """A field that is a name, at most :data:`NAME_MAX_CHARS`; ValueError else."""
    if len(text) > NAME_MAX_CHARS:
        raise ValueError(f"chronyc tracking: {name} of {len(text)} characters")
    return text


def read_chrony_tracking(
    socket: str | None = None, timeout_s: float = TIMEOUT_S
) -> ChronyTracking | Absent:
    """chrony's tracking now, asked through ``chronyc`` (of the command socket
    ``socket``, a path, when given; else chronyc's default), waiting at most
    ``timeout_s``; :class:`Absent` when chronyc is not installed, chronyd does not
    answer, or the answer is not a tracking report (:func:`parse_tracking`)."""
    chronyc = shutil.which("chronyc")
    if chronyc is None:
        return Absent("chronyc not installed")
    command = [chronyc, "-c", "-n"]
    if socket is not None:
        command += ["-h", socket]
    done = ask_tool([*command, "tracking"], "chronyc", timeout_s)
    if isinstance(done, Absent):
        return done
    if done.returncode != 0 or not done.stdout.strip():
        why = (done.stderr or done.stdout).strip().splitlines()
        return Absent(f"chronyd not answering ({why[-1] if why else f'exit {done.returncode}'})")
    try:
        return parse_tracking(done.stdout.strip().splitlines()[-1])
    except ValueError as e:
        return Absent(str(e))
