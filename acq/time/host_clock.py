"""What the host knows about its clock, gathered once a second off the recorder's
writer thread: the kernel's discipline status (:mod:`acq.time.kernel_clock`), chrony's
tracking (:mod:`acq.time.chrony`), ptp4l's time status (:mod:`acq.time.ptp`), a kernel
PPS source (:mod:`acq.time.pps`), and the GNSS receiver's time against the host clock
(given by the recorder). A source that is not there is :class:`acq.time.absent.Absent`.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, replace

from acq.time.absent import Absent
from acq.time.chrony import ChronyTracking, read_chrony_tracking
from acq.time.kernel_clock import KernelClock, read_kernel_clock
from acq.time.pps import PpsSource, read_pps
from acq.time.ptp import PtpTime, read_ptp_time

__all__ = [
    "NO_GNSS", "GnssTime", "HostClock", "HostClockPoller", "gnss_time", "read_host_clock",
]  # fmt: skip

NO_GNSS = Absent("no GNSS receiver")

log = logging.getLogger("acq.time.host_clock")


@dataclass(frozen=True)
class GnssTime:
    """The GNSS receiver's time against the host clock: ``host_minus_gnss_s`` the host's
    UTC at a fix's receipt, less the receiver's ``latency_s``, minus the fix's UTC, s
    (positive: the host clock is ahead); ``fix_age_s`` since the last fix, s."""

    host_minus_gnss_s: float
    latency_s: float
    fix_age_s: float


def gnss_time(
    receipt_minus_fix_ns: int, latency_s: float, fix_age_s: float, realtime_minus_monotonic_ns: int
) -> GnssTime:
    """:class:`GnssTime` from the host monotonic time of a fix's receipt minus the fix's
    UTC, ns, and the host's UTC minus monotonic now, ns."""
    host = (receipt_minus_fix_ns + realtime_minus_monotonic_ns) * 1e-9 - latency_s
    return GnssTime(host, latency_s, fix_age_s)


@dataclass(frozen=True)
class HostClock:
    """One reading of the host clock's sources, taken at ``realtime_ns``
    (CLOCK_REALTIME) and ``monotonic_ns`` (CLOCK_MONOTONIC), read together."""

    realtime_ns: int
    monotonic_ns: int
    kernel: KernelClock | Absent
    chrony: ChronyTracking | Absent
    ptp: PtpTime | Absent
    pps: PpsSource | Absent
    gnss: GnssTime | Absent = NO_GNSS

    @property
    def synchronised(self) -> bool:
        """Something disciplines the host clock to UTC: chrony follows a reference,
        ptp4l a grandmaster, or the kernel calls its clock synchronised."""
        return (
            (isinstance(self.chrony, ChronyTracking) and self.chrony.synchronised)
            or (isinstance(self.ptp, PtpTime) and self.ptp.gm_present)
            or (isinstance(self.kernel, KernelClock) and self.kernel.synchronised)
        )


def read_host_clock(chrony_socket: str | None = None) -> HostClock:
    """Every source now (each with its own short timeout); ``chrony_socket``: chronyd's
    command socket, chronyc's default when None."""
    kernel = read_kernel_clock()
    chrony = read_chrony_tracking(chrony_socket)
    ptp = read_ptp_time()
    pps = read_pps()
    return HostClock(
        realtime_ns=time.time_ns(),
        monotonic_ns=time.monotonic_ns(),
        kernel=kernel if kernel is not None else Absent("adjtimex not available"),
        chrony=chrony,
        ptp=ptp,
        pps=pps,
    )


class HostClockPoller:
    """A daemon thread reading :func:`read_host_clock` every ``period_s``: the writer
    takes the newest reading with :meth:`take` and never waits for a source."""

    def __init__(self, period_s: float = 1.0, chrony_socket: str | None = None) -> None:
        self.period_s = period_s
        self.chrony_socket = chrony_socket
        self._latest: HostClock | None = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="host-clock", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()

    def _run(self) -> None:
        failing = False
        while not self._stop.is_set():
            started = time.monotonic()
            try:
                reading = read_host_clock(self.chrony_socket)
            except Exception as e:  # an unforeseen failure must not end the time base
                if not failing:
                    log.warning("reading the host clock's sources failed (%s: %s); trying "
                                "again every %g s", type(e).__name__, e, self.period_s)  # fmt: skip
                failing = True
            else:
                if failing:
                    log.warning("the host clock's sources are read again")
                failing = False
                with self._lock:
                    self._latest = reading
            self._stop.wait(max(self.period_s - (time.monotonic() - started), 0.05))

    def take(self, gnss: GnssTime | Absent = NO_GNSS) -> HostClock | None:
        """The newest reading not taken yet (with ``gnss`` added), or None."""
        with self._lock:
            reading, self._latest = self._latest, None
        return None if reading is None else replace(reading, gnss=gnss)
