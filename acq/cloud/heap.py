"""The C heap of a colouring run: large blocks handed back to the system when freed.

glibc's malloc serves blocks above its mmap threshold with mmap, returned to the system
on free, but it raises that threshold to the size of each such block freed (up to
32 MB), after which a chunk's arrays of a few MB come from the heap, where what is freed
stays in the process (holes between live blocks). A fixed threshold keeps those arrays
mmapped; each mmapped block's pages fault in anew (system time), so not too low. On the
60 s two-camera demo drive, peak memory and system CPU of ``acq colorize`` (load 10):
dynamic 620-680 MB, 0.6-0.8 s; fixed at 4 MB 613-627 MB, 0.6-0.7 s; at 2 MB 558-564 MB,
1.1-1.2 s; at 256 KB 533-544 MB, 1.8-2.2 s.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

__all__ = ["MMAP_THRESHOLD", "large_blocks_returned"]

MMAP_THRESHOLD = 2 * 2**20  # bytes: blocks from this size up are mmapped
_M_MMAP_THRESHOLD = -3  # mallopt's parameter (malloc.h)


def large_blocks_returned() -> bool:
    """Fix glibc's mmap threshold at MMAP_THRESHOLD for this process (its dynamic
    raising off); False where the C library is not glibc (nothing changed)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # musl has no mallopt
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD))
