"""chrony's tracking report, as ``chronyc -c tracking`` gives it: which reference the
host follows, how far the host clock was from it, and whether chrony calls it
synchronised. Read through ``chronyc`` with a short timeout; a missing ``chronyc`` or a
``chronyd`` that does not answer is :class:`acq.time.absent.Absent`, not an error.
"""

from __future__ import annotations

import shutil
import subprocess
from dataclasses import dataclass

from acq.time.absent import Absent

__all__ = ["ChronyTracking", "parse_tracking", "read_chrony_tracking"]

TIMEOUT_S = 0.5


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
    """A ``chronyc -c tracking`` line (14 comma-separated fields); ValueError if not one."""
    f = line.strip().split(",")
    if len(f) != 14:
        raise ValueError(f"chronyc tracking: {len(f)} fields, expected 14: {line.strip()!r}")
    return ChronyTracking(
        reference_id=int(f[0], 16),
        reference_name=f[1],
        stratum=int(f[2]),
        ref_time_s=float(f[3]),
        system_offset_s=float(f[4]),
        last_offset_s=float(f[5]),
        rms_offset_s=float(f[6]),
        frequency_ppm=float(f[7]),
        residual_frequency_ppm=float(f[8]),
        skew_ppm=float(f[9]),
        root_delay_s=float(f[10]),
        root_dispersion_s=float(f[11]),
        update_interval_s=float(f[12]),
        leap_status=f[13],
    )


def read_chrony_tracking(
    socket: str | None = None, timeout_s: float = TIMEOUT_S
) -> ChronyTracking | Absent:
    """chrony's tracking now, asked through ``chronyc`` (of the command socket
    ``socket``, a path, when given; else chronyc's default), waiting at most
    ``timeout_s``; :class:`Absent` when chronyc is not installed or chronyd does not
    answer."""
    chronyc = shutil.which("chronyc")
    if chronyc is None:
        return Absent("chronyc not installed")
    command = [chronyc, "-c", "-n"]
    if socket is not None:
        command += ["-h", socket]
    try:
        done = subprocess.run(
            [*command, "tracking"], capture_output=True, text=True, timeout=timeout_s, check=False
        )
    except subprocess.TimeoutExpired:
        return Absent(f"chronyc gave no answer within {timeout_s:g} s")
    except OSError as e:
        return Absent(f"chronyc cannot run: {e.strerror or e}")
    if done.returncode != 0 or not done.stdout.strip():
        why = (done.stderr or done.stdout).strip().splitlines()
        return Absent(f"chronyd not answering ({why[-1] if why else f'exit {done.returncode}'})")
    try:
        return parse_tracking(done.stdout.strip().splitlines()[-1])
    except ValueError as e:
        return Absent(str(e))
