"""SICK's own driver, sick_scan_xd, run against a simulated or replayed scanner.

:func:`run_sick_scan` starts this module as a child process: it loads sick_scan_xd's
shared library through SICK's Python API (``api/sick_scan_api.py`` in
``../shared/tools/vendor-clients/sick/``), initialises it with a model's launch file and
only ``hostname:=`` / ``port:=`` overrides, and writes one line per polar point cloud
the driver delivers to a pipe of its own. The parent collects those lines for a bounded
time, then kills the child with SIGKILL (the library's threads do not always end on
``SickScanApiClose``).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

VENDOR = Path(__file__).resolve().parents[2] / "shared" / "tools" / "vendor-clients" / "sick"


@dataclass(frozen=True)
class Cloud:
    """One polar point cloud as sick_scan_xd delivered it: host receive time (monotonic
    s), width, azimuths of the first and last point (rad), points with a range > 0, the
    largest intensity."""

    t: float
    width: int
    azimuth_first: float
    azimuth_last: float
    valid: int
    intensity_max: float


@dataclass
class Run:
    """What one run of the driver delivered, and the tail of its log (for messages)."""

    clouds: list[Cloud] = field(default_factory=list)
    log: list[str] = field(default_factory=list)

    def rate(self) -> float:
        """Clouds per second over what was delivered (first to last)."""
        if len(self.clouds) < 2:
            return 0.0
        span = self.clouds[-1].t - self.clouds[0].t
        return (len(self.clouds) - 1) / span if span > 0 else 0.0

    def tail(self, n: int = 30) -> str:
        return "\n".join(self.log[-n:])


def available() -> bool:
    return (VENDOR / "libsick_scan_xd_shared_lib.so").is_file()


def run_sick_scan(launch: str, port: int, clouds: int, timeout_s: float) -> Run:
    """Run sick_scan_xd with ``launch`` (a file in the vendor's ``launch/``) against
    127.0.0.1:``port`` until it delivered ``clouds`` point clouds or ``timeout_s`` passed;
    the child is killed either way. The clouds come on a pipe of their own, the
    library's log on the child's stdout."""
    read_fd, write_fd = os.pipe()
    cmd = [sys.executable, "-u", __file__, str(VENDOR / "launch" / launch), str(port)]
    try:
        proc = subprocess.Popen(
            [*cmd, str(write_fd)],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            errors="replace",
            start_new_session=True,
            pass_fds=(write_fd,),
        )
    finally:
        os.close(write_fd)
    run = Run()
    done = threading.Event()

    def read_clouds() -> None:
        with os.fdopen(read_fd, encoding="utf-8", errors="replace") as lines:
            for line in lines:
                run.clouds.append(Cloud(**json.loads(line)))
                if len(run.clouds) >= clouds:
                    done.set()
        done.set()

    def read_log() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            run.log.append(line.rstrip())
            del run.log[:-200]

    readers = [threading.Thread(target=f, daemon=True) for f in (read_clouds, read_log)]
    for reader in readers:
        reader.start()
    done.wait(timeout_s)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(5.0)
    for reader in readers:
        reader.join(5.0)
    return run


def _child(launch: str, port: int, out_fd: int) -> None:
    """Runs in the child: initialise sick_scan_xd and write each polar cloud to
    ``out_fd``, one JSON line each."""
    import ctypes

    import numpy as np

    sys.path.insert(0, str(VENDOR / "api"))
    import sick_scan_api as api  # type: ignore[import-not-found]

    out = os.fdopen(out_fd, "w", buffering=1)
    lib = api.SickScanApiLoadLibrary([str(VENDOR) + "/"], "libsick_scan_xd_shared_lib.so")
    handle = api.SickScanApiCreate(lib)

    def on_cloud(_handle: object, msg_ptr: object) -> None:
        msg = msg_ptr.contents  # type: ignore[attr-defined]
        t = time.monotonic()
        fields = {
            msg.fields.buffer[i].name.decode(): msg.fields.buffer[i].offset
            for i in range(msg.fields.size)
        }
        n = msg.width * msg.height
        raw = ctypes.string_at(msg.data.buffer, msg.data.size)
        rows = np.frombuffer(raw, np.uint8).reshape(n, msg.point_step)

        def column(name: str) -> np.ndarray:
            k = fields[name]
            return rows[:, k : k + 4].copy().view(np.float32).ravel()

        azimuth, ranges = column("azimuth"), column("range")
        intensity = column("intensity") if "intensity" in fields else np.zeros(1, np.float32)
        line = {
            "t": t,
            "width": int(msg.width),
            "azimuth_first": float(azimuth[0]) if n else 0.0,
            "azimuth_last": float(azimuth[-1]) if n else 0.0,
            "valid": int(np.count_nonzero(ranges > 0)),
            "intensity_max": float(intensity.max()) if n else 0.0,
        }
        out.write(json.dumps(line) + "\n")

    callback = api.SickScanPointCloudMsgCallback(on_cloud)
    api.SickScanApiRegisterPolarPointCloudMsg(lib, handle, callback)
    args = f"{launch} hostname:=127.0.0.1 port:={port}"
    api.SickScanApiInitByLaunchfile(lib, handle, args)
    while True:  # the parent kills this process
        time.sleep(1.0)


if __name__ == "__main__":
    _child(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]))
