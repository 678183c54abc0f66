"""bench/colorize_speed.py's measure of a process: wall time, peak memory and CPU time."""

from __future__ import annotations

import sys

from tests.bench_scripts import load

BUSY = "import time\nt = time.process_time()\nwhile time.process_time() - t < 0.3: pass\nprint(1)"


def test_a_process_measured_with_its_cpu_time_and_peak_memory() -> None:
    speed = load("colorize_speed")
    wall, _, cpu, out = speed.measured([sys.executable, "-c", BUSY])
    assert out == "1\n"
    assert 0.3 <= cpu <= wall + 0.5  # the child's own CPU, not its parent's
    grow = "b = bytearray(200 * 2**20)\nb[::4096] = b'x' * len(b[::4096])"
    _, peak, _, _ = speed.measured([sys.executable, "-c", grow])
    assert peak >= 200  # MB, the 200 MB it touched
    _, _, idle, _ = speed.measured([sys.executable, "-c", "import time; time.sleep(0.4)"])
    assert idle < 0.3  # waiting takes no CPU
