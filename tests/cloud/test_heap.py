"""acq.cloud.heap: glibc's mmap threshold fixed for a colouring run."""

from __future__ import annotations

import platform
import subprocess
import sys

from acq.cloud import heap


def test_the_threshold_is_fixed_where_the_c_library_is_glibc() -> None:
    """In a process of its own (it changes the whole process's allocator): True on
    glibc, and a block above the threshold is mmapped and handed back when freed (the
    resident size falls back), which the dynamic threshold would keep in the heap after
    a first such block was freed."""
    glibc = sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc"
    code = """
import sys
from acq.cloud import heap

def rss():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096

ok = heap.large_blocks_returned()
first = bytearray(8 * 2**20)  # above the dynamic threshold: mmapped, and its free
del first                     # raises the dynamic threshold to 8 MB
base = rss()
block = bytearray(4 * 2**20)  # below 8 MB, above the fixed 2 MB
held = rss() - base
del block
print(ok, held > 3 * 2**20, rss() - base < 2**20)
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    ok, touched, returned = out.stdout.split()
    assert ok == str(glibc)
    if glibc:
        assert touched == "True" and returned == "True"
    assert heap.MMAP_THRESHOLD == 2 * 2**20
