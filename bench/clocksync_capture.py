"""Clock synchronisation on a real device (issue 5): the LMS111 capture, one JSON line
per figure group.

The capture (``../shared/data/sick/20210302_lms111.pcapng.json``) is a CoLa-B session
with a real LMS111 recorded on the host. The device's stream is reassembled without its
TCP retransmissions (``tests.wireshark_json``) and framed; each scan's device stamp is its
``time_since_startup`` (32-bit µs) and its host time is the capture time at which its
last byte arrived. Reported: the scans, ``acq.time.clocksync.fit_drift`` (drift with its 95 %
interval, the delays above the lower envelope), the scan period on both clocks, and the
delays left by ``acq.time.clocksync.retime_offline`` (receipt minus re-timed stamp; the
constant latency is invisible to one-way timing, so the minimum is about 0). Absent
capture: one line saying so.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from acq.drivers.cola_codec import ColaFramer, Telegram
from acq.drivers.cola_scandata import parse_scandata
from acq.time.clocksync import fit_drift, retime_offline

# the capture reader is a test helper (tests/wireshark_json.py), not part of acq: the
# repository's root on the path, as pytest has it
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.wireshark_json import read_packets, reassemble, split_directions

CAPTURE = (
    Path(__file__).resolve().parents[2] / "shared" / "data" / "sick" / "20210302_lms111.pcapng.json"
)
REQUESTS = (b"sMN", b"sRN", b"sWN", b"sEN")
TICK_HZ = 1e6  # SICK: µs
WRAP_BITS = 32


def from_device(payload: bytes) -> bool | None:
    """CoLa-B direction from content (the export has no addresses): a payload that starts
    a telegram is a host request (sMN/sRN/sWN/sEN) or a device telegram; None otherwise."""
    if payload[:4] != b"\x02\x02\x02\x02" or len(payload) < 11:
        return None
    return payload[8:11] not in REQUESTS


@dataclass(frozen=True)
class Arrivals:
    """The capture's scans: device stamps (µs ticks), counters, and capture times (s)."""

    ticks: np.ndarray  # (N,) int64, time_since_startup, µs
    tx_ticks: np.ndarray  # (N,) int64, time_of_transmission, µs
    counters: np.ndarray  # (N,) int64, scan counter
    recv_s: np.ndarray  # (N,) float64, capture s when the scan's last byte arrived
    retransmissions: int  # device packets dropped as TCP retransmissions


def scan_arrivals(path: Path = CAPTURE) -> Arrivals:
    """Every LMDscandata scan of the capture with the capture time of its last byte."""
    _, device = split_directions(read_packets(path), from_server=from_device)
    stream = reassemble(device)
    framer = ColaFramer("b")
    framer.feed(stream.data)
    ends: list[int] = []
    scans = []
    pos = 0
    for item in framer.items():
        if not isinstance(item, Telegram):
            raise ValueError(f"{path}: {item}")
        pos = stream.data.index(item.raw, pos) + len(item.raw)
        if item.kind == "sSN" and item.name == "LMDscandata":
            scans.append(parse_scandata(item.raw))
            ends.append(pos - 1)
    return Arrivals(
        ticks=np.array([s.time_since_startup for s in scans], dtype=np.int64),
        tx_ticks=np.array([s.time_of_transmission for s in scans], dtype=np.int64),
        counters=np.array([s.scan_counter for s in scans], dtype=np.int64),
        recv_s=stream.times_at(ends),
        retransmissions=len(stream.dropped),
    )


def _ms(x: float) -> float:
    return round(x * 1e3, 4)


def figures(a: Arrivals) -> list[dict[str, Any]]:
    """The figure groups of the bench, as JSON-ready dicts."""
    dev_s = np.unwrap(a.ticks.astype(np.float64), period=2.0**WRAP_BITS) / TICK_HZ
    span = float(a.recv_s[-1] - a.recv_s[0])
    fit = fit_drift(dev_s, a.recv_s)
    turns = float(a.counters[-1] - a.counters[0])
    recv_ns = np.round(a.recv_s * 1e9).astype(np.int64)
    retimed = retime_offline(a.ticks, recv_ns, tick_hz=TICK_HZ, wrap_bits=WRAP_BITS)
    late = (recv_ns - retimed) * 1e-9  # s
    tx_s = np.unwrap(a.tx_ticks.astype(np.float64), period=2.0**WRAP_BITS) / TICK_HZ
    tx_fit = fit_drift(tx_s, a.recv_s)
    return [
        {
            "figure": "scans",
            "scans": int(a.ticks.size),
            "counters": [int(a.counters[0]), int(a.counters[-1])],
            "lost": int(turns + 1 - a.counters.size),
            "retransmissions_dropped": a.retransmissions,
            "span_s": round(span, 4),
        },
        {
            "figure": "drift",
            "drift_ppm": round(fit.drift_ppm, 1),
            "ci95_ppm": [round(v, 1) for v in fit.drift_ci_ppm],
            "offset_s": round(fit.offset_s, 6),
        },
        {
            "figure": "delay_above_envelope",
            "stamp": "time_since_startup",
            "median_ms": _ms(fit.residual_median_s),
            "p95_ms": _ms(fit.residual_p95_s),
            "max_ms": _ms(fit.residual_max_s),
        },
        {
            "figure": "scan_period",
            "device_ms": round((dev_s[-1] - dev_s[0]) / turns * 1e3, 5),
            "capture_ms": round(span / turns * 1e3, 5),
            "device_hz": round(turns / (dev_s[-1] - dev_s[0]), 4),
            "capture_hz": round(turns / span, 4),
        },
        {
            "figure": "retime_offline",
            "recv_minus_retimed_min_ms": _ms(float(late.min())),
            "median_ms": _ms(float(np.median(late))),
            "p95_ms": _ms(float(np.quantile(late, 0.95))),
        },
        {
            "figure": "delay_above_envelope",
            "stamp": "time_of_transmission",
            "drift_ppm": round(tx_fit.drift_ppm, 1),
            "ci95_ppm": [round(v, 1) for v in tx_fit.drift_ci_ppm],
            "median_ms": _ms(tx_fit.residual_median_s),
            "p95_ms": _ms(tx_fit.residual_p95_s),
            "max_ms": _ms(tx_fit.residual_max_s),
            "stamp_to_tx_median_ms": _ms(float(np.median(tx_s - dev_s))),
        },
    ]


def main() -> None:
    head = {"bench": "clocksync_capture", "device": "lms111"}
    if not CAPTURE.is_file():
        print(json.dumps({**head, "skipped": f"{CAPTURE} is absent"}))
        return
    for fig in figures(scan_arrivals(CAPTURE)):
        print(json.dumps({**head, **fig}), flush=True)


if __name__ == "__main__":
    main()
