"""Peak memory of the COPC writer against the drive's length: one JSON line per result.

For each drive length (default 5 minutes and an hour), a child process does only this:
feed :class:`acq.cloud.copc.CopcStream` the points of a synthesised drive
(:mod:`acq.sim.long_cloud`: along a 30-km arc with the 2-camera demo rig's density,
126 M points an hour) in 10-s parts as ``acq colorize`` writes them, then close it.
Reported: ``peak_rss_mb`` (the child's ``ru_maxrss``), ``write_s`` and ``close_s``
(seconds), ``points`` and ``file_mb``. Target: a peak independent of the length,
at most 1.5 GB for the hour. The output and the scratch files (46 bytes a point, up to
twice that while a level spills) go to ``--dir``, removed after each run.

With ``--log SRC`` (an acq log, e.g. the demo's), the whole command too: for each length
a drive synthesised from SRC (``bench/hour_log.py``) is coloured by ``acq colorize LOG
--calib CALIB -o x.copc.laz`` (CALIB: ``calib.yaml`` beside SRC unless ``--calib``), with
the defaults a user gets, in a child whose peak RSS is read from ``wait4`` (``case``
``colorize``: ``peak_rss_mb``, ``seconds``, ``log_mb``).
Run as a script: ``python bench/copc_memory.py [--minutes 5 60] [--dir DIR] [--log SRC]``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # run as a script or loaded by path
from hour_log import write_hour_log


def _child(seconds: float, out: Path) -> None:
    from acq.cloud.copc import CopcStream
    from acq.sim.long_cloud import parts

    t0 = time.perf_counter()
    stream = CopcStream(out, cameras=["left", "right"])
    points = 0
    for p in parts(seconds):
        stream.write(*p)
        points += p[0].shape[0]
    t1 = time.perf_counter()
    size = stream.close()
    t2 = time.perf_counter()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KB on Linux
    out.unlink()
    line = {"bench": "copc_memory", "case": "writer", "drive_s": seconds, "points": points,
            "peak_rss_mb": round(peak, 1), "write_s": round(t1 - t0, 1),
            "close_s": round(t2 - t1, 1), "file_mb": round(size / 1e6, 1)}  # fmt: skip
    print(json.dumps(line), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, nargs="+", default=[5.0, 60.0],
                        help="drive lengths to measure, minutes (default: 5 60)")  # fmt: skip
    parser.add_argument("--dir", type=Path, default=None,
                        help="folder for the output and scratch files (default: a "
                        "temporary folder)")  # fmt: skip
    parser.add_argument("--log", type=Path, default=None,
                        help="also colour a drive of each length synthesised from this "
                        "acq log with acq colorize")  # fmt: skip
    parser.add_argument("--calib", type=Path, default=None,
                        help="its calibration (default: calib.yaml beside --log)")  # fmt: skip
    parser.add_argument("--child", type=float, help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child is not None:
        _child(args.child, args.out)
        return
    with tempfile.TemporaryDirectory(dir=args.dir, prefix="copc-memory-") as d:
        for minutes in args.minutes:
            subprocess.run(
                [sys.executable, __file__, "--child", str(minutes * 60),
                 "--out", str(Path(d) / "bench.copc.laz")],
                check=True,
            )  # fmt: skip
            if args.log is not None:
                calib = args.calib or args.log.with_name("calib.yaml")
                _colorize(args.log, calib, minutes, Path(d))


def _colorize(src: Path, calib: Path, minutes: float, work: Path) -> None:
    """``acq colorize`` of a ``minutes`` drive synthesised from ``src`` to COPC, in a
    child: one JSON line with its peak RSS and seconds."""
    log, out = work / "drive.mcap", work / "drive.copc.laz"
    write_hour_log(src, log, minutes)
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        [sys.executable, "-m", "acq.cli", "colorize", str(log), "--calib", str(calib),
         "-o", str(out)],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    err = proc.stderr.read() if proc.stderr else ""
    _pid, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    seconds = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"acq colorize exited {proc.returncode}: {err[-2000:]}")
    line = {"bench": "copc_memory", "case": "colorize", "drive_s": minutes * 60,
            "log_mb": round(log.stat().st_size / 1e6), "peak_rss_mb":
            round(usage.ru_maxrss / 1024, 1), "seconds": round(seconds, 1),
            "file_mb": round(out.stat().st_size / 1e6, 1)}  # fmt: skip
    print(json.dumps(line), flush=True)
    log.unlink()
    out.unlink()


if __name__ == "__main__":
    main()
