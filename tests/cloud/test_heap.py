"""acq.cloud.heap: the heap's free memory handed back to the system."""

from __future__ import annotations

import platform
import subprocess
import sys

_CODE = """
import sys
from acq.cloud import heap

def rss():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096

first = bytearray(16 * 2**20)  # mmapped; freeing it raises glibc's mmap threshold
del first
hole = bytearray(8 * 2**20)    # now from the heap,
keep = bytearray(64 * 2**10)   # below a block that stays (no trimming from the top)
base = rss()
del hole                       # freed, still resident
freed = rss()
done = heap.give_back() if sys.argv[1] == "give" else False
print(done, (base - freed) // 2**20, (base - rss()) // 2**20)
"""


def _run(mode: str) -> list[str]:
    done = subprocess.run([sys.executable, "-c", _CODE, mode], capture_output=True, text=True,
                          check=True)  # fmt: skip
    return done.stdout.split()


def test_free_heap_memory_goes_back_to_the_system() -> None:
    """In a process of its own (the allocator is the whole process's): a block freed
    inside the heap, which glibc usually keeps resident, is not resident once handed
    back (True on glibc)."""
    glibc = sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc"
    given = _run("give")
    assert given[0] == str(glibc)
    if glibc:
        assert int(given[2]) >= 7  # the 8 MB block's pages back to the system
