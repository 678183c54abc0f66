"""`acq record --live` with a client that subscribes to everything and never reads: the
recorder's memory growth and what the log lost, one JSON line.

Runs ``acq record -c CONFIG --live`` (e.g. the rig of ``acq sim rig --out D``: a UTM-30LX
at 40 Hz with intensities, two 780x582 fisheyes at 25 Hz, CAN and GNSS) for
``--seconds``; after ``--settle`` seconds a WebSocket client speaking ``foxglove.sdk.v1``
subscribes to every channel advertised and then never reads again. The recorder's RSS
(``/proc/PID/status`` VmRSS) is sampled each second: ``rss_at_stall_mb`` when the client
stalls, ``rss_max_after_mb`` the highest after; ``dropped`` sums the devices' dropped
records in the log's last ``/acq/status``; ``largest_message_kb`` is the log's largest.

    acq sim rig --out /tmp/rig &
    python bench/live_stalled_client.py -c /tmp/rig/rig.yaml --seconds 60
    python bench/live_stalled_client.py -c /tmp/rig/rig.yaml --seconds 60 --no-live
"""

from __future__ import annotations

import argparse
import asyncio
import json
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from acq.monitor.foxglove_client import Seen, connect_client, take


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


async def _stall(url: str, settle_s: float) -> None:
    """Connect, subscribe to everything advertised within ``settle_s``, stop reading."""
    ws = await connect_client(url, max_queue=1)
    await take(ws, Seen(), time.monotonic() + settle_s, decode=False)
    _HELD.append(ws)  # never read again, the connection held open


_HELD: list[object] = []


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-c", "--config", required=True)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--settle", type=float, default=3.0)
    ap.add_argument("--no-live", action="store_true", help="the baseline: no --live, no client")
    args = ap.parse_args()
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    out = Path(tempfile.mkdtemp(prefix="live-bench-"))
    live = [] if args.no_live else ["--live", f"127.0.0.1:{port}"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "acq.cli", "record", "-c", args.config, "--out", str(out),
         "--duration", str(args.seconds), *live],
        stderr=subprocess.DEVNULL,
    )  # fmt: skip
    loop = asyncio.new_event_loop()
    if args.no_live:
        loop.run_until_complete(asyncio.sleep(args.settle))
    else:
        loop.run_until_complete(_stall(f"ws://127.0.0.1:{port}", args.settle))
    at_stall = _rss_mb(proc.pid)
    peak = at_stall
    while proc.poll() is None:
        loop.run_until_complete(asyncio.sleep(1.0))  # the client's socket stays unread
        try:
            peak = max(peak, _rss_mb(proc.pid))
        except (FileNotFoundError, ProcessLookupError):
            break
    proc.wait()
    status, largest = None, 0
    for path in sorted(out.glob("*.mcap")):
        with path.open("rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for _, channel, message, decoded in reader.iter_decoded_messages():
                largest = max(largest, len(message.data))
                if channel.topic == "/acq/status":
                    status = decoded
    dropped = {d.name: d.dropped for d in status.devices} if status is not None else None
    print(json.dumps({
        "seconds": args.seconds, "exit": proc.returncode, "rss_at_stall_mb": round(at_stall, 1),
        "rss_max_after_mb": round(peak, 1), "growth_mb": round(peak - at_stall, 1),
        "dropped": dropped, "largest_message_kb": round(largest / 1024, 1),
    }))  # fmt: skip


if __name__ == "__main__":
    main()
