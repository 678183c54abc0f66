"""What `acq status` costs each second on a long log being written: acq.log.tail's first
look and each later poll (one second of new data), against one whole pass of the log's
reader (what a view that re-read the file would pay every second).

``python bench/status_tail.py [--seconds 600] [--bytes-per-s 500000]`` writes a log with
the recorder's LogWriter, still open (being written): each second a status and
incompressible filler (never decoded, a camera's share of the bytes), one chunk a
second as the recorder syncs; prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

from acq.log import schemas
from acq.log.reader import LogReader, quiet
from acq.log.tail import LogTail
from acq.log.writer import LogWriter


def _second(w: LogWriter, s: int, filler: int) -> None:
    t = s * 1_000_000_000
    w.write("/acq/status", schemas.status(timestamp_ns=t, uptime_s=float(s)), t, t)
    w.write("/filler", os.urandom(filler), t, t)
    w.sync()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=int, default=600, help="seconds of log (default 600)")
    ap.add_argument("--bytes-per-s", type=int, default=500_000, help="filler per second")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        w = LogWriter(Path(tmp), split_bytes=1 << 40, split_s=1e9, profile="acq")
        w.add_channel("/acq/status", schemas.SCHEMAS["acq.Status"])
        w.add_channel("/filler", schemas.SCHEMAS["acq.RawTelegram"])  # its bytes never read
        for s in range(1, args.seconds + 1):
            _second(w, s, args.bytes_per_s)
        assert w.path is not None
        size = w.path.stat().st_size
        t0 = time.perf_counter()
        tail = LogTail(w.path, ["/acq/status", "/acq/timebase"])
        first = tail.poll()
        t1 = time.perf_counter()
        _second(w, args.seconds + 1, args.bytes_per_s)
        t2 = time.perf_counter()
        later = tail.poll()
        t3 = time.perf_counter()
        with quiet():
            whole = sum(1 for _, c, _ in LogReader(w.path, progress=False).messages())
        t4 = time.perf_counter()
        assert later and later[-1].decoded.uptime_s == args.seconds + 1
        w.close()
    print(json.dumps({
        "bench": "status_tail", "bytes": size, "seconds": args.seconds,
        "first_poll_ms": round((t1 - t0) * 1e3, 1), "first_poll_messages": len(first),
        "next_poll_ms": round((t3 - t2) * 1e3, 2), "whole_read_ms": round((t4 - t3) * 1e3),
        "whole_read_messages": whole, "loadavg": [round(x, 2) for x in os.getloadavg()],
    }))  # fmt: skip


if __name__ == "__main__":
    main()
