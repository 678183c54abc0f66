"""Receive-time jitter of a scanner read in a busy recorder process (issue 5), one JSON
line per condition.

A simulated UTM-30LX (SCIP 2.0, 40 Hz, 24-bit ms clock running ``SIM_DRIFT_PPM`` fast)
runs in its own process (``acq sim scanner``); a thread of this process reads it with
the real driver (``acq.drivers.scip.ScipScanner``) for ``--seconds``, in three conditions:
``idle``; ``busy_gil``, one more thread doing pure-Python work that holds the GIL (a
writer serialising messages by hand); ``busy_nogil``, one more thread doing zlib and
numpy work that releases the GIL (compression); ``busy_gil_switch_1ms``, the first
again with the thread switch interval lowered to 1 ms (what ``acq record`` does).
CPython hands the GIL to a waiting thread only every ``sys.getswitchinterval()`` (5 ms
by default), and the reader waits for it after each blocking call.

Per condition: the delays above the lower envelope of (device s, host receive s), from
``acq.time.clocksync.fit_drift``'s line (``jitter_*``: on the raw ms ticks, which quantise
the stamp by up to a tick; ``jitter_turns_*``: on device times fitted to the turn
numbers, which do not), p50/p95/p99/max in ms; scans and lost scans; and the cost:
the RMS and max of ``DeviceClock`` online estimates (update, then ``to_host_ns`` of the
same tick) about ``retime_offline`` of the same log, ms, after a ``WARMUP_S`` warm-up.
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
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TextIO

import numpy as np
from processes import acq_command, end, start_simulator

from acq.drivers.scip import ScipScanner
from acq.time.clocksync import DeviceClock, fit_drift, retime_offline

MODEL = "utm-30lx"
SIM_DRIFT_PPM = 50.0  # a real crystal's order; the fit should find about -50
TICK_HZ = 1000.0
WRAP_BITS = 24
WARMUP_S = 5.0


@dataclass(frozen=True)
class Log:
    """What the reader thread saw: device ticks (ms) and host receive ns per scan."""

    ticks: np.ndarray  # (N,) int64
    recv_ns: np.ndarray  # (N,) int64
    busy_ops: int  # units of work the busy thread finished meanwhile


# --- the simulated device, in its own process -------------------------------------------


def start_scanner(stderr: TextIO) -> tuple[subprocess.Popen[str], str]:
    """``acq sim scanner`` on a free port; the process and its socket:// URL."""
    cmd = [*acq_command(), "sim", "scanner", "--model", MODEL, "--drift-ppm", str(SIM_DRIFT_PPM)]
    return start_simulator(cmd, " on socket://", stderr)


# --- busy work ------------------------------------------------------------------------------


def gil_work() -> None:
    """Pure Python holding the GIL: protobuf-style varints of 2,000 fields (~1 ms)."""
    out = bytearray()
    for i in range(2000):
        v = (i * 2654435761) & 0xFFFFFFFF
        while v >= 0x80:
            out.append((v & 0x7F) | 0x80)
            v >>= 7
        out.append(v)


_BLOCK = np.random.default_rng(0).integers(0, 16, 1 << 18, dtype=np.uint8).tobytes()
_A = np.linspace(1.0, 2.0, 1 << 20)
_B = np.empty_like(_A)


def nogil_work() -> None:
    """zlib and numpy, which release the GIL while they run: 256 KiB deflated, 1 M sqrt."""
    zlib.compress(_BLOCK, 6)
    np.sqrt(_A, out=_B)
    np.multiply(_B, 1.000001, out=_B)


# condition: (busy work, thread switch interval in s); the last is the remedy the
# recorder applies (sys.setswitchinterval(0.001)) against the first's cost
WORK: dict[str, tuple[Callable[[], None] | None, float]] = {
    "idle": (None, 0.005),
    "busy_gil": (gil_work, 0.005),
    "busy_nogil": (nogil_work, 0.005),
    "busy_gil_switch_1ms": (gil_work, 0.001),
}


# --- one condition --------------------------------------------------------------------------


def record(url: str, seconds: float, work: Callable[[], None] | None) -> Log:
    """Read scans for ``seconds`` in a reader thread while ``work`` runs in another."""
    stop = threading.Event()
    ops = [0]
    ticks: list[int] = []
    recv: list[int] = []
    failure: list[BaseException] = []

    def busy() -> None:
        assert work is not None
        while not stop.is_set():
            work()
            ops[0] += 1

    def read() -> None:
        scanner = ScipScanner(url, timeout=2.0)
        try:
            scanner.connect()
            scanner.start()
            deadline = time.monotonic() + seconds
            while time.monotonic() < deadline:
                scan = scanner.read_scan()
                ticks.append(scan.device_ticks[0])
                recv.append(scan.recv_ns)
        except BaseException as e:
            failure.append(e)
        finally:
            scanner.close()

    worker = threading.Thread(target=busy, daemon=True) if work is not None else None
    reader = threading.Thread(target=read, daemon=True)
    try:
        if worker is not None:
            worker.start()
            time.sleep(0.5)
        reader.start()
        reader.join(seconds + 30.0)
    finally:
        stop.set()
        if worker is not None:
            worker.join(5.0)
    if reader.is_alive():
        raise RuntimeError(f"{url}: the reader did not finish")
    if failure:
        raise RuntimeError(f"{url}: {type(failure[0]).__name__}: {failure[0]}")
    return Log(np.array(ticks, dtype=np.int64), np.array(recv, dtype=np.int64), ops[0])


# --- analysis -------------------------------------------------------------------------------


def _quantiles_ms(prefix: str, delay_s: np.ndarray) -> dict[str, float]:
    p50, p95, p99 = np.quantile(delay_s, [0.5, 0.95, 0.99]) * 1e3
    return {
        f"{prefix}_p50_ms": round(float(p50), 3),
        f"{prefix}_p95_ms": round(float(p95), 3),
        f"{prefix}_p99_ms": round(float(p99), 3),
        f"{prefix}_max_ms": round(float(delay_s.max()) * 1e3, 3),
    }


def _above_envelope(device_s: np.ndarray, host_s: np.ndarray) -> tuple[np.ndarray, float]:
    """Delays (s) above fit_drift's lower-envelope line, and its drift (ppm)."""
    fit = fit_drift(device_s, host_s)
    x0 = float(device_s.min())
    line = x0 + fit.offset_s + (1.0 + fit.drift_ppm * 1e-6) * (device_s - x0)
    return host_s - line, fit.drift_ppm


def analyse(log: Log, seconds: float) -> dict[str, Any]:
    """The figures of one condition (see the module docstring)."""
    u = np.unwrap(log.ticks.astype(np.float64), period=float(1 << WRAP_BITS))
    host_s = (log.recv_ns - log.recv_ns[0]) * 1e-9
    steps = np.diff(u)
    period = float(np.median(steps))
    turns = np.concatenate([[0.0], np.cumsum(np.round(steps / period))])
    raw, drift = _above_envelope((u + 0.5) / TICK_HZ, host_s)
    fitted = np.polyval(np.polyfit(turns, u + 0.5, 1), turns) / TICK_HZ
    smooth, _ = _above_envelope(fitted, host_s)
    clock = DeviceClock(tick_hz=TICK_HZ, wrap_bits=WRAP_BITS)
    online = np.empty(log.ticks.size)
    for i, (t, r) in enumerate(zip(log.ticks.tolist(), log.recv_ns.tolist(), strict=True)):
        clock.update(t, r)
        online[i] = clock.to_host_ns(t)
    offline = retime_offline(log.ticks, log.recv_ns, tick_hz=TICK_HZ, wrap_bits=WRAP_BITS)
    warm = host_s >= WARMUP_S
    cost = (online - offline)[warm] * 1e-6  # ms
    return {
        "seconds": seconds,
        "scans": int(log.ticks.size),
        "lost": int(turns[-1] + 1 - turns.size),
        "period_ms": round(period, 3),
        "busy_ops_per_s": round(log.busy_ops / seconds, 1),
        **_quantiles_ms("jitter", raw),
        **_quantiles_ms("jitter_turns", smooth),
        "drift_ppm": round(drift, 1),
        "online_vs_offline_rms_ms": round(float(np.sqrt(np.mean(cost**2))), 4),
        "online_vs_offline_max_ms": round(float(np.abs(cost).max()), 4),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=30.0, help="per condition (default 30)")
    args = parser.parse_args()
    if args.seconds < WARMUP_S + 5:
        parser.error(f"--seconds must be at least {WARMUP_S + 5:g}")
    head = {"bench": "receive_jitter", "model": MODEL}
    setup = {
        "condition": "setup",
        "sim_drift_ppm": SIM_DRIFT_PPM,
        "expected_drift_ppm": round((1 / (1 + SIM_DRIFT_PPM * 1e-6) - 1) * 1e6, 2),
        "switch_interval_ms": sys.getswitchinterval() * 1e3,
        "cpus": os.cpu_count(),
        "python": sys.version.split()[0],
    }
    print(json.dumps({**head, **setup}), flush=True)
    with tempfile.TemporaryFile("w+") as err:
        proc, url = start_scanner(err)
        try:
            record(url, 2.0, None)  # warm-up: the simulator compiles its ray caster
            default_switch = sys.getswitchinterval()
            for condition, (work, switch_s) in WORK.items():
                sys.setswitchinterval(switch_s)
                try:
                    log = record(url, args.seconds, work)
                finally:
                    sys.setswitchinterval(default_switch)
                figures = analyse(log, args.seconds)
                figures["switch_interval_ms"] = switch_s * 1e3
                print(json.dumps({**head, "condition": condition, **figures}), flush=True)
        except RuntimeError as e:
            err.seek(0)
            print(f"receive_jitter: {e}\n{err.read()}", file=sys.stderr)
            return 1
        finally:
            end(proc)
    return 0


if __name__ == "__main__":
    sys.exit(main())
