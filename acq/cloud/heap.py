"""The C heap of a colouring run: what is freed handed back to the system.

glibc's malloc keeps freed memory in the process to serve later blocks, and once a few
large blocks have been freed it serves arrays of up to 32 MB from the heap, where what
is freed stays resident. ``acq colorize`` hands it back (``malloc_trim``) after reading
the log's light part (about 90 MB read and dropped), after each chunk is written and
before the preview: on the 60 s two-camera demo drive, 625-650 MB at the peak instead of
680-710, at the same speed. A fixed, lower mmap threshold (``mallopt``) returned more
(2 MB: 575-600 MB) but faulted every chunk's arrays in anew: 20-40 % slower.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import sys
from collections.abc import Callable
from typing import cast

__all__ = ["give_back"]


@functools.cache
def _malloc_trim() -> Callable[[int], int] | None:
    """glibc's ``malloc_trim``, looked up once (None: not Linux, or a C library without
    it, such as musl)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        trim = libc.malloc_trim
    except (OSError, AttributeError):
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return cast("Callable[[int], int]", trim)


def give_back() -> bool:
    """Hand the heap's free memory back to the system (glibc's ``malloc_trim(0)``);
    False where the C library has none (nothing done)."""
    trim = _malloc_trim()
    if trim is None:
        return False
    trim(0)
    return True
