"""`acq record --live` measured: its CPU cost, the latency to a client, a stalled client's
cost. One JSON line per result, each with ``os.getloadavg()`` (2 cores, shared).

The rig: ``-c CONFIG`` (a running rig's configuration), else ``acq sim rig`` started here
(a UTM-30LX at 40 Hz with intensities, two 780x582 fisheyes at 25 Hz, CAN, GNSS; each
device in a process of its own). ``acq record`` runs as a subprocess; its CPU is that of
its own process tree (``/proc``), never the rig's.

(1) ``live_cpu``: the recorder's CPU share of one core over ``--cpu-s`` after
    ``--warmup-s``, recording without ``--live``, then the same with ``--live`` and one
    client subscribed to every channel and reading, then (when the configuration has a
    ``calibration``, which makes the recorder colour) the same again without it, so
    that the server's cost and the colouring's are told apart (``--rounds`` such runs,
    medians). Target: ``overhead`` (live less plain) at most 0.05 of a core.
(2) ``live_latency``: from a scan's last point (its stamp + (points - 1) x the
    ``time_increment`` of the log's ``device.<laser>`` geometry, taken off the log's UTC
    offset) to a reading client's receipt, on loopback: median and p99 over
    ``--latency-s``, one line per topic: the coloured scans ``/<laser>/colored``
    (``present`` false, no figures, while the recorder publishes none) and the raw scans
    ``/<laser>/scan``. Target (coloured): p99 at most 150 ms.
(3) ``live_stalled``: in the same recording, after (2)'s window, a second client
    subscribes to every channel and never reads again for ``--stall-s``: the recorder's
    RSS growth from the stall to the end (target at most 50 MB), records lost (the
    scans in the log against the scanner's ticks between the first and the last; each
    device's ``dropped`` in the last ``/acq/status``, and in the (2) window and the
    stall from the statuses the reading client received; a listener's "fell behind"
    lines) and the reading client's latency without (the (2) window) and with the
    stalled one. ``ok`` judges the scanner's records: a camera's ``dropped`` also counts
    frames its driver infers lost from time gaps (the sim rig's cameras render live
    after ``--prerender`` s, late on a busy host), so it is shown, not judged.

    python bench/live.py [--cpu] [--latency] [--stalled] [-c CONFIG] [--quick]

No part named: all three ((2) and (3) share one recording). ``--quick``: 10 s windows.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from processes import Procs, Run, acq_command, free_port, tree_cpu_s, wait_line, workdir
from recorder import nominal_scans, read_recorded
from websockets.exceptions import ConnectionClosed

from acq.log.reader import read_metadata
from acq.log.timebase import TimeBase

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the client: a test helper
from acq.monitor.foxglove_client import Seen, connect_client, take

TARGET_OVERHEAD = 0.05  # of a core
TARGET_P99_MS = 150.0
TARGET_GROWTH_MB = 50.0
RIG_START_S = 300.0  # the cameras render --prerender s of frames first, slow on a busy host


def _line(bench: str, **values: Any) -> None:
    print(json.dumps({"bench": bench, **values, "loadavg": [round(x, 2) for x in os.getloadavg()]}),
          flush=True)  # fmt: skip


# --- the rig, the recorder, the clients ---------------------------------------------------


def start_rig(procs: Procs, work: Path, prerender_s: float, stderr: Any) -> Path:
    """``acq sim rig`` in ``work/rig``, its devices up: the path of its rig.yaml."""
    cmd = ["sim", "rig", "--out", str(work / "rig"), "--prerender", f"{prerender_s:g}"]
    proc = procs.start([*acq_command(), *cmd], stdout=subprocess.PIPE, stderr=stderr)
    wait_line(proc, "rig.yaml", RIG_START_S)
    return work / "rig" / "rig.yaml"


def devices(config: Path) -> tuple[str, list[str]]:
    """(the first scanner's name, every scanner's and camera's name) of a configuration."""
    data = yaml.safe_load(config.read_text())
    names = [d["name"] for d in (*data.get("scanners", []), *data.get("cameras", []))]
    return data["scanners"][0]["name"], names


def record(
    procs: Procs, config: Path, out: Path, live_port: int | None, extra: Sequence[str] = ()
) -> Run:
    """``acq record -c config --out out`` (with ``--live`` on ``live_port``, and ``extra``
    options), its scanners and cameras connected."""
    live = [] if live_port is None else ["--live", f"127.0.0.1:{live_port}"]
    live += extra
    log = out.with_suffix(".log")
    with log.open("w") as err:
        t0 = time.monotonic()
        proc = procs.start(
            [*acq_command(), "record", "-c", str(config), "--out", str(out), *live], stderr=err
        )
    run = Run(proc, out, log, t0)
    run.wait_for(*(f"{name} connected" for name in devices(config)[1]), timeout=60.0)
    return run


class Client:
    """A ``foxglove.sdk.v1`` client on a thread of its own, subscribed to every channel.
    Reading: every message is read and counted, those of ``timed`` topics decoded and kept
    with their receipt time (``seen.messages``). Stalled: it subscribes within
    ``settle_s`` and then never reads again (its socket's buffers fill; no keepalive
    pings, whose answers it would never read)."""

    def __init__(self, port: int, timed: set[str], stalled: bool = False, settle_s: float = 3.0):
        self.url = f"ws://127.0.0.1:{port}"
        self.timed, self.stalled, self.settle_s = timed, stalled, settle_s
        self.seen = Seen(keep=timed.__contains__)
        self.closed = ""  # why the connection closed before close(), if it did
        self.subscribed = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=lambda: asyncio.run(self._run()), daemon=True)
        self._thread.start()

    async def _run(self) -> None:
        # no size limit: /live/swath is up to 300,000 points (4.8 MB), over websockets' 1 MB
        kw: dict[str, Any] = {"max_size": None}
        if self.stalled:
            kw |= {"max_queue": 1, "ping_interval": None}
        ws = await connect_client(self.url, **kw)
        try:
            await take(ws, self.seen, time.monotonic() + self.settle_s, decode=True)
            self.subscribed.set()
            while not self._stop.is_set():
                if self.stalled:
                    await asyncio.sleep(0.2)
                else:
                    await take(ws, self.seen, time.monotonic() + 0.2, decode=True)
        except ConnectionClosed as e:
            self.closed = str(e)
        finally:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(ws.close(), 2.0)

    def received(self, topic: str, lo: float, hi: float) -> list[tuple[float, Any]]:
        """The kept messages of ``topic`` received in [lo, hi) (host monotonic s)."""
        return [m for m in list(self.seen.messages.get(topic, [])) if lo <= m[0] < hi]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5.0)


# --- the measures -------------------------------------------------------------------------


def last_point_s(metadata: dict[str, dict[str, str]], laser: str) -> float:
    """Seconds from a scan's stamp (its point 0) to its last point, from the log's
    ``device.<laser>`` geometry."""
    geometry = json.loads(metadata[f"device.{laser}"]["geometry"])
    return (int(geometry["n_points"]) - 1) * float(geometry["time_increment"])


def latencies_ms(
    received: list[tuple[float, Any]], utc_offset_ns: int, last_point: float
) -> np.ndarray:
    """Receipt (host monotonic s) less each message's last point, ms: its ``timestamp``
    is in the log's time base (host monotonic + ``utc_offset_ns``)."""
    recv_ns = np.array([t for t, _ in received], dtype=np.float64) * 1e9
    stamp_ns = np.array(
        [m.timestamp.seconds * 10**9 + m.timestamp.nanos - utc_offset_ns for _, m in received],
        dtype=np.float64,
    )
    return (recv_ns - stamp_ns) / 1e6 - last_point * 1e3


def drops_between(statuses: list[tuple[float, Any]], lo: float, hi: float) -> dict[str, int]:
    """Each device's records dropped between the last ``/acq/status`` received before
    ``lo`` (or the first after) and the last before ``hi``."""
    inside = [m for t, m in statuses if t < hi]
    if not inside:
        return {}
    first = next((m for t, m in reversed(statuses) if t < lo), inside[0])
    start = {d.name: d.dropped for d in first.devices}
    return {d.name: d.dropped - start.get(d.name, 0) for d in inside[-1].devices}


def latency_figures(ms: np.ndarray) -> dict[str, Any]:
    """Median, p99 and max of latencies (ms); None for each when there are none."""
    if ms.size == 0:
        return {"messages": 0, "median_ms": None, "p99_ms": None, "max_ms": None}
    return {
        "messages": int(ms.size),
        "median_ms": round(float(np.median(ms)), 2),
        "p99_ms": round(float(np.percentile(ms, 99)), 2),
        "max_ms": round(float(ms.max()), 2),
    }


def _log_clock(run: Run, laser: str) -> tuple[int, float]:
    """(the UTC offset, the scan's last-point time) of the recording's first file."""
    metadata = read_metadata(run.files()[0])
    return TimeBase.of_metadata(metadata).utc_offset_ns, last_point_s(metadata, laser)


# --- (1) CPU --------------------------------------------------------------------------------


def _cpu_window(run: Run, warmup_s: float, seconds: float) -> tuple[float, float]:
    """(CPU share of one core of the recorder's process tree, wall s) over the window."""
    run.sleep_until(max(warmup_s, time.monotonic() - run.t_start + 1.0))
    t0, c0 = time.monotonic(), tree_cpu_s(run.proc.pid)
    run.sleep_until(time.monotonic() - run.t_start + seconds)
    t1, c1 = time.monotonic(), tree_cpu_s(run.proc.pid)
    return (c1 - c0) / (t1 - t0), t1 - t0


def _rates(run: Run, seconds: float) -> dict[str, float]:
    info = read_recorded(run.files()).info
    return {c.topic: round(c.count / seconds, 1) for c in info.channels
            if c.topic.endswith(("/scan", "/image/compressed", "/colored"))}  # fmt: skip


def uncalibrated(config: Path, work: Path) -> Path | None:
    """A copy of ``config`` without its ``calibration`` (no live colouring), in ``work``;
    None when it has none."""
    data = yaml.safe_load(config.read_text())
    if not data.pop("calibration", None):
        return None
    path = work / "rig_uncalibrated.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _live_cpu(procs: Procs, config: Path, out: Path, warmup_s: float, seconds: float
              ) -> tuple[float, dict[str, float], Client]:  # fmt: skip
    """One recording with --live and a reading client: (CPU share, rates, the client)."""
    port = free_port()
    run = record(procs, config, out, port)
    client = Client(port, set())
    client.subscribed.wait(30.0)
    share, _ = _cpu_window(run, warmup_s, seconds)
    client.close()
    run.stop()
    return share, _rates(run, run.wall_s), client


def part_cpu(procs: Procs, config: Path, work: Path, warmup_s: float, seconds: float,
             rounds: int) -> None:  # fmt: skip
    laser, _ = devices(config)
    colored = f"/{laser}/colored"
    bare = uncalibrated(config, work)
    shares: dict[str, list[float]] = {"plain": [], "live": [], "live_uncoloured": []}
    rates: dict[str, dict[str, float]] = {}
    clients: dict[str, Client] = {}
    for k in range(rounds):
        run = record(procs, config, work / f"cpu_plain_{k}", None)
        share, _ = _cpu_window(run, warmup_s, seconds)
        run.stop()
        shares["plain"].append(share)
        rates["plain"] = _rates(run, run.wall_s)
        runs = {"live": config, "live_uncoloured": bare} if bare else {"live": config}
        for name, cfg in runs.items():
            out = work / f"cpu_{name}_{k}"
            share, rates[name], clients[name] = _live_cpu(procs, cfg, out, warmup_s, seconds)
            shares[name].append(share)
    p, q = float(np.median(shares["plain"])), float(np.median(shares["live"]))
    u = float(np.median(shares["live_uncoloured"])) if bare else None
    counts = dict(clients["live"].seen.counts)
    closed = {name: c.closed for name, c in clients.items() if c.closed}
    _line(
        "live_cpu", seconds=seconds, rounds=rounds, cpu_share_plain=round(p, 4),
        cpu_share_live=round(q, 4), overhead=round(q - p, 4),
        # the same rig without its calibration: --live serving the log's channels, no colouring
        cpu_share_live_uncoloured=None if u is None else round(u, 4),
        overhead_uncoloured=None if u is None else round(u - p, 4),
        per_round={name: [round(x, 4) for x in v] for name, v in shares.items() if v},
        colored_present=colored in counts, client_messages=counts, clients_closed=closed,
        recorded_hz=rates, target_overhead=TARGET_OVERHEAD,
        ok=q - p <= TARGET_OVERHEAD and not closed,
    )  # fmt: skip


# --- (2) latency and (3) the stalled client ------------------------------------------------


def part_live(procs: Procs, config: Path, work: Path, warmup_s: float, latency_s: float,
              stall_s: float, report_latency: bool, report_stall: bool) -> None:  # fmt: skip
    laser, _ = devices(config)
    topics = [f"/{laser}/colored", f"/{laser}/scan"]
    port = free_port()
    run = record(procs, config, work / "live", port)
    reader = Client(port, {*topics, "/acq/status"})
    reader.subscribed.wait(30.0)
    run.sleep_until(max(warmup_s, time.monotonic() - run.t_start))
    free_lo = time.monotonic()
    run.sleep_until(time.monotonic() - run.t_start + latency_s)
    free_hi = time.monotonic()
    stalled = None
    rss_at_stall = peak = 0.0
    if report_stall:
        stalled = Client(port, set(), stalled=True)
        stalled.subscribed.wait(30.0)
        rss_at_stall = peak = run.sample()[2]
        while time.monotonic() - free_hi < stall_s:
            run.sleep_until(time.monotonic() - run.t_start + 1.0)
            peak = max(peak, run.sample()[2])
    stall_hi = time.monotonic()
    reader.close()
    if stalled is not None:
        stalled.close()
    run.stop()
    offset, last_point = _log_clock(run, laser)

    def figures(topic: str, lo: float, hi: float) -> dict[str, Any]:
        got = reader.received(topic, lo, hi)
        return {"present": bool(got), **latency_figures(latencies_ms(got, offset, last_point))}

    if report_latency:
        for topic in topics:
            _line("live_latency", topic=topic, seconds=round(free_hi - free_lo, 1),
                  **figures(topic, free_lo, free_hi), reader_closed=reader.closed,
                  target_p99_ms=TARGET_P99_MS,
                  exit_code=run.exit_code)  # fmt: skip
    if report_stall:
        rec = read_recorded(run.files())
        status = rec.last_status
        dropped = {d.name: d.dropped for d in status.devices} if status is not None else None
        nominal = nominal_scans(rec.scan_ticks)
        statuses = reader.received("/acq/status", 0.0, stall_hi)
        before, during = (
            drops_between(statuses, free_lo, free_hi),
            drops_between(statuses, free_hi, stall_hi),
        )
        behind = [w for w in run.warnings() if "fell behind" in w]
        latency = {
            topic: {
                "without_stalled": figures(topic, free_lo, free_hi),
                "with_stalled": figures(topic, free_hi, stall_hi),
            }
            for topic in topics
        }
        growth = peak - rss_at_stall
        # a camera's dropped also counts the frames its driver infers lost from time gaps
        # (a live-rendering sim camera running late): shown, not judged
        lost = len(rec.scan_ticks) != nominal or (dropped or {}).get(laser, 1) > 0 or bool(behind)
        _line(
            "live_stalled", stall_s=round(stall_hi - free_hi, 1),
            rss_at_stall_mb=round(rss_at_stall, 1), rss_max_after_mb=round(peak, 1),
            growth_mb=round(growth, 1), scans=f"{len(rec.scan_ticks)}/{nominal}",
            dropped=dropped, dropped_without_stalled=before, dropped_with_stalled=during,
            listeners_behind=behind, reader_latency=latency,
            stalled_client_messages=stalled.seen.counts if stalled is not None else None,
            stalled_client_closed=stalled.closed if stalled is not None else None,
            reader_closed=reader.closed,
            exit_code=run.exit_code, target_growth_mb=TARGET_GROWTH_MB,
            ok=growth <= TARGET_GROWTH_MB and not lost and run.exit_code == 0 and not reader.closed,
        )  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cpu", action="store_true", help="(1) CPU with and without --live")
    ap.add_argument("--latency", action="store_true", help="(2) latency to a reading client")
    ap.add_argument("--stalled", action="store_true", help="(3) a client that never reads")
    ap.add_argument("-c", "--config", type=Path, help="a running rig's configuration "
                    "(default: acq sim rig, started here)")  # fmt: skip
    ap.add_argument("--prerender", type=float, default=60.0, help="acq sim rig --prerender S")
    ap.add_argument("--warmup-s", type=float, default=5.0, help="from the recorder's start")
    ap.add_argument("--cpu-s", type=float, default=30.0, help="(1) each window")
    ap.add_argument("--rounds", type=int, default=1, help="(1) pairs of recordings")
    ap.add_argument("--latency-s", type=float, default=30.0, help="(2) window")
    ap.add_argument("--stall-s", type=float, default=60.0, help="(3) the stall")
    ap.add_argument("--quick", action="store_true", help="10 s windows")
    ap.add_argument("--keep", action="store_true", help="keep the logs (their folder on stderr)")
    args = ap.parse_args()
    if args.quick:
        args.cpu_s = args.latency_s = args.stall_s = 10.0
    every = not (args.cpu or args.latency or args.stalled)
    procs = Procs()
    with workdir("live-bench-", args.keep) as work, (work / "sim.log").open("w") as err:
        try:
            config = args.config or start_rig(procs, work, args.prerender, err)
            if args.cpu or every:
                part_cpu(procs, config, work, args.warmup_s, args.cpu_s, args.rounds)
            if args.latency or args.stalled or every:
                part_live(procs, config, work, args.warmup_s, args.latency_s, args.stall_s,
                          args.latency or every, args.stalled or every)  # fmt: skip
        finally:
            procs.close()


if __name__ == "__main__":
    main()
