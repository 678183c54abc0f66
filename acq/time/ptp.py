"""linuxptp's view of the host's PTP time: ``pmc -u -b 0 'GET TIME_STATUS_NP'`` asked of
a running ``ptp4l`` (its Unix socket), with a short timeout. No ``pmc``, no ``ptp4l``
socket or no answer is :class:`acq.time.absent.Absent`, not an error.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

from acq.time.absent import Absent
from acq.time.tool_answer import ask_tool

__all__ = ["PTP4L_SOCKET", "PtpTime", "parse_time_status", "read_ptp_time"]

PTP4L_SOCKET = Path("/var/run/ptp4l")  # ptp4l's default management socket
TIMEOUT_S = 0.5
IDENTITY_MAX_CHARS = 64  # a clock identity: 8 bytes, 23 characters as pmc prints it


@dataclass(frozen=True)
class PtpTime:
    """ptp4l's TIME_STATUS_NP: ``master_offset_s`` the PTP clock minus the grandmaster,
    s; ``gm_present`` whether a grandmaster is followed, ``gm_identity`` its clock
    identity (hex with dots, as pmc prints it)."""

    master_offset_s: float
    gm_present: bool
    gm_identity: str


def parse_time_status(text: str) -> PtpTime:
    """pmc's answer to ``GET TIME_STATUS_NP``; ValueError without one."""
    values: dict[str, str] = {}
    for line in text.splitlines():
        parts = line.split()
        if len(parts) == 2:
            values[parts[0]] = parts[1]
    try:
        offset, identity = values["master_offset"], values["gmIdentity"]
        if len(offset) > 24 or len(identity) > IDENTITY_MAX_CHARS:
            raise ValueError
        return PtpTime(
            master_offset_s=int(offset) / 1e9,
            gm_present=values["gmPresent"] == "true",
            gm_identity=identity,
        )
    except (KeyError, ValueError):
        raise ValueError("pmc: no TIME_STATUS_NP in the answer") from None


def read_ptp_time(socket: Path = PTP4L_SOCKET, timeout_s: float = TIMEOUT_S) -> PtpTime | Absent:
    """ptp4l's time status now, or :class:`Absent` (no pmc, ptp4l not running, no
    answer within ``timeout_s``)."""
    pmc = shutil.which("pmc")
    if pmc is None:
        return Absent("pmc (linuxptp) not installed")
    if not socket.exists():
        return Absent("ptp4l not running")
    command = [pmc, "-u", "-b", "0", "-s", str(socket), "GET TIME_STATUS_NP"]
    done = ask_tool(command, "pmc", timeout_s)
    if isinstance(done, Absent):
        return done
    try:
        return parse_time_status(done.stdout)
    except ValueError:
        return Absent("ptp4l gave no time status")
