"""`acq replay`'s memory: the peak resident size of the replaying process before a client
connects and after serving for a while, on a given log. One JSON line per result.

``acq replay LOG... --speed X --config-out CFG`` runs in a child process. Once it waits for
a client, its peak RSS (``VmHWM`` of ``/proc/PID/status``) is read (``before_client``);
then a client per scanner (the driver of the replay's configuration: SCIP or CoLa) and
per camera (the OpenCV driver reading MJPEG over HTTP) reads what the replay serves for
``--seconds`` (15) s (keep it under the log's length divided by the speed: the replay
ends with the log), the child is stopped and its peak over its whole life is taken from
``wait4`` (``ru_maxrss``, the ``VmHWM`` at exit; ``after_serving``, with the records each
client got). ``--minutes M`` first synthesises an M-minute drive from the log
(``bench/hour_log.py``, one file in a temporary folder), so an hour can be made from the
demo's 10 s. Target: a peak independent of the
log's length (500 MB for an hour-long drive).

Run as a script: ``python bench/replay_memory.py --log out/demo/demo.mcap [--minutes 60]
[--speed 10] [--seconds 15]``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from acq.drivers.camera_opencv import OpenCVCamera
from acq.drivers.registry import REGISTRIES
from acq.record import config as configfile

sys.path.insert(0, str(Path(__file__).resolve().parent))  # run as a script or loaded by path
from hour_log import write_hour_log


def _line(**values: Any) -> None:
    load = [round(x, 2) for x in os.getloadavg()]
    print(json.dumps({"bench": "replay_memory", **values, "loadavg": load}), flush=True)


def peak_mb(pid: int) -> tuple[float, float]:
    """(VmHWM, VmRSS) of process ``pid``, MB."""
    fields = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key, _, value = line.partition(":")
        fields[key] = value.split()
    return int(fields["VmHWM"][0]) / 1024, int(fields["VmRSS"][0]) / 1024


class Client:
    """Reads one replayed device in a thread until stopped: records and bytes got."""

    def __init__(self, name: str, opener: Any, read: str) -> None:
        self.name = name
        self.opener = opener
        self.read = read
        self.records = 0
        self.bytes = 0
        self.error: str | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        device = self.opener()
        try:
            device.connect()
            device.start()
            while not self._stop.is_set():
                got = getattr(device, self.read)()
                self.records += 1
                self.bytes += len(got.raw if hasattr(got, "raw") else got.jpeg)
        except Exception as e:  # the log ended (a timeout) or the link dropped
            if not self._stop.is_set():
                self.error = f"{type(e).__name__}: {e}"
        finally:
            device.close()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(10.0)


def clients(cfg: configfile.Config) -> list[Client]:
    out = []
    for s in cfg.scanners:
        options: dict[str, Any] = dict(s.options)
        if s.protocol is not None:
            options["protocol"] = s.protocol

        def scanner(s: Any = s, options: dict[str, Any] = options) -> Any:
            return REGISTRIES["scanner"].create(s.driver, s.url, name=s.name, **options)

        out.append(Client(s.name, scanner, "read_scan"))
    for c in cfg.cameras:
        out.append(Client(c.name, lambda c=c: OpenCVCamera(c.source, timeout=5.0), "read_frame"))
    return out


def measure(logs: list[Path], speed: float, seconds: float, work: Path) -> None:
    config = work / "replay.yaml"
    cmd = [sys.executable, "-m", "acq.cli", "replay", *map(str, logs), "--speed", str(speed),
           "--config-out", str(config)]  # fmt: skip
    t0 = time.monotonic()
    err = (work / "replay.err").open("w+")
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, text=True)
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            if line.startswith("the replay starts"):
                break
        else:
            raise RuntimeError(f"acq replay exited {proc.wait()} before serving")
        ready_s = time.monotonic() - t0
        time.sleep(0.5)
        if proc.poll() is not None:
            err.seek(0)
            raise RuntimeError(f"acq replay exited {proc.returncode}: {err.read()[-2000:]}")
        hwm, rss = peak_mb(proc.pid)
        size = sum(p.stat().st_size for p in logs) / 1e6
        _line(case="before_client", log_mb=round(size), ready_s=round(ready_s, 1),
              vmhwm_mb=round(hwm, 1), vmrss_mb=round(rss, 1))  # fmt: skip
        readers = clients(configfile.load(config))
        time.sleep(seconds)
        for r in readers:
            r.stop()
        proc.terminate()
        _pid, status, usage = os.wait4(proc.pid, 0)  # the peak over its whole life
        proc.returncode = os.waitstatus_to_exitcode(status)
        got = {r.name: r.records for r in readers}
        errors = {r.name: r.error for r in readers if r.error}
        _line(case="after_serving", log_mb=round(size), speed=speed, seconds=seconds,
              maxrss_mb=round(usage.ru_maxrss / 1024, 1), records=got,
              mb_read=round(sum(r.bytes for r in readers) / 1e6, 1), errors=errors)  # fmt: skip
    finally:
        if proc.returncode is None:
            proc.kill()
            proc.wait()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--log", type=Path, action="append", required=True,
                   help="a log (repeat for the files of a session, in order)")  # fmt: skip
    p.add_argument("--minutes", type=float, default=None,
                   help="replay a drive of this length synthesised from the log by "
                   "bench/hour_log.py (default: the log as it is)")  # fmt: skip
    p.add_argument("--speed", type=float, default=10.0, help="replay speed (default 10)")
    p.add_argument("--seconds", type=float, default=15.0,
                   help="how long the clients read (default 15)")  # fmt: skip
    args = p.parse_args()
    with tempfile.TemporaryDirectory(prefix="replay-memory-") as tmp:
        work = Path(tmp)
        logs = args.log
        if args.minutes is not None:
            logs = [work / "long.mcap"]
            write_hour_log(args.log[0], logs[0], args.minutes)
        measure(logs, args.speed, args.seconds, work)


if __name__ == "__main__":
    main()
