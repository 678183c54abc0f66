"""The kernel's record of how well the host clock is disciplined: ``adjtimex(2)`` read
without changing anything (``modes`` 0), which any process may do.

Whatever disciplines the clock (chrony, ntpd, ptp4l's phc2sys, a PPS discipline) keeps
the kernel's status: ``STA_UNSYNC`` set and the clock state ``TIME_ERROR`` mean the
clock is not synchronised to anything; ``maxerror`` is the kernel's bound on the error,
which grows by 500 ppm of the time since the last update. Linux only; elsewhere
:func:`read_kernel_clock` returns None.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys
from dataclasses import dataclass

__all__ = ["KernelClock", "read_kernel_clock"]

STA_PLL = 0x0001
STA_PPSTIME = 0x0004
STA_UNSYNC = 0x0040
STA_NANO = 0x2000
TIME_ERROR = 5  # adjtimex's return value: the clock is not synchronised
STATES = {0: "ok", 1: "leap second insert", 2: "leap second delete", 3: "leap second now",
          4: "leap second done", 5: "unsynchronised"}  # fmt: skip


class _Timeval(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_usec", ctypes.c_long)]


class _Timex(ctypes.Structure):
    """``struct timex`` of <sys/timex.h> (Linux, LP64 and ILP32 alike: longs and ints)."""

    _fields_ = [
        ("modes", ctypes.c_uint),
        ("offset", ctypes.c_long),
        ("freq", ctypes.c_long),
        ("maxerror", ctypes.c_long),
        ("esterror", ctypes.c_long),
        ("status", ctypes.c_int),
        ("constant", ctypes.c_long),
        ("precision", ctypes.c_long),
        ("tolerance", ctypes.c_long),
        ("time", _Timeval),
        ("tick", ctypes.c_long),
        ("ppsfreq", ctypes.c_long),
        ("jitter", ctypes.c_long),
        ("shift", ctypes.c_int),
        ("stabil", ctypes.c_long),
        ("jitcnt", ctypes.c_long),
        ("calcnt", ctypes.c_long),
        ("errcnt", ctypes.c_long),
        ("stbcnt", ctypes.c_long),
        ("tai", ctypes.c_int),
        ("_padding", ctypes.c_int * 11),
    ]


@dataclass(frozen=True)
class KernelClock:
    """The kernel's discipline status. ``synchronised``: neither ``STA_UNSYNC`` nor the
    ``TIME_ERROR`` state; ``state`` the clock state's name; ``maxerror_s`` and
    ``esterror_s`` the kernel's maximum and estimated error, s; ``offset_s`` the
    discipline's last phase offset, s; ``freq_ppm`` its frequency correction; ``pll``
    and ``pps`` whether the kernel PLL and a PPS signal discipline it; ``tai_s`` TAI
    minus UTC where set (0 where not)."""

    synchronised: bool
    state: str
    maxerror_s: float
    esterror_s: float
    offset_s: float
    freq_ppm: float
    pll: bool
    pps: bool
    tai_s: int


def _libc() -> ctypes.CDLL | None:
    if not sys.platform.startswith("linux"):
        return None
    name = ctypes.util.find_library("c")
    return ctypes.CDLL(name, use_errno=True) if name else None


def read_kernel_clock() -> KernelClock | None:
    """The kernel's status now, or None where ``adjtimex`` is not to be had (not Linux,
    or the call refused)."""
    libc = _libc()
    if libc is None:
        return None
    tx = _Timex()  # modes 0: read only
    state = int(libc.adjtimex(ctypes.byref(tx)))
    if state < 0:
        return None
    offset = tx.offset * (1e-9 if tx.status & STA_NANO else 1e-6)
    return KernelClock(
        synchronised=state != TIME_ERROR and not tx.status & STA_UNSYNC,
        state=STATES.get(state, str(state)),
        maxerror_s=tx.maxerror * 1e-6,
        esterror_s=tx.esterror * 1e-6,
        offset_s=offset,
        freq_ppm=tx.freq / 65536.0,
        pll=bool(tx.status & STA_PLL),
        pps=bool(tx.status & STA_PPSTIME),
        tai_s=int(tx.tai),
    )
