"""GNSS fix stamps against the simulated receiver's truth, one JSON line per run.

The recorder records ``--seconds`` of a simulated UTM-30LX (on TCP) and the simulated NMEA
receiver (on a pty: 10 Hz, sentences 40 ms after the fix instant plus up to 12 ms of
jitter, its UTC the host's wall clock) with ``gnss.time`` as ``--time`` says and
``gnss.latency_s`` as ``--latency``. ``--disciplined`` makes the recorder take the host
clock for disciplined (:func:`acq.time.kernel_clock.read_kernel_clock` replaced, as this
sandbox's clock is not); without it the kernel's own answer stands.

Per run: each fix's stamp minus its true fix instant (ms: median, p95 of the absolute
value, max), its receipt minus the true instant, and what ``acq info`` says of the log's
fixes (receipt minus fix time, stamping).

Run as a script: ``python bench/gnss_time.py [--time auto|fix|receipt] [--disciplined]``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from acq.record import config as configfile
from acq.record.recorder import Recorder
from acq.sim.nmea_device import NmeaDevice, NmeaPtyServer
from acq.sim.scanner_models import MODELS
from acq.sim.scip_device import ScipDevice
from acq.sim.transport import TcpDeviceServer
from acq.time import kernel_clock


def _stats(ms: np.ndarray) -> dict[str, float]:
    return {
        "median_ms": round(float(np.median(ms)), 3),
        "p95_abs_ms": round(float(np.percentile(np.abs(ms), 95)), 3),
        "max_abs_ms": round(float(np.max(np.abs(ms))), 3),
    }


def measure(work: Path, seconds: float, stamping: str | None, latency: float) -> dict[str, Any]:
    from acq.log import info
    from acq.log.reader import LogReader

    gnss = NmeaDevice()
    servers = (TcpDeviceServer(ScipDevice(MODELS["utm-30lx"])).start(), NmeaPtyServer(gnss).start())
    try:
        section: dict[str, Any] = {"url": servers[1].url, "baudrate": 115200, "latency_s": latency}
        if stamping is not None:
            section["time"] = stamping
        data = {
            "version": 1,
            "scanners": [{"name": "laser", "driver": "hokuyo", "url": servers[0].url}],
            "gnss": section,
            "output": {"dir": str(work / "logs")},
        }
        (work / "rig.yaml").write_text(yaml.safe_dump(data))
        Recorder(configfile.load(work / "rig.yaml"), duration_s=seconds).run()
    finally:
        for s in servers:
            s.close()
    (path,) = sorted((work / "logs").glob("*.mcap"))
    truth = {round(t.utc_s, 2): t.t for t in gnss.truth}
    reader = LogReader(path)
    stamp_err, recv_delay = [], []
    for schema, channel, message in reader.messages():
        if channel.topic != "/gnss/fix":
            continue
        m = reader.decode(schema, channel, message)
        utc = float({kv.key: kv.value for kv in m.metadata}["utc_s"])
        t = truth[round(utc, 2)]
        stamp_err.append((message.publish_time * 1e-9 - t) * 1e3)
        recv_delay.append((message.log_time * 1e-9 - t) * 1e3)
    summary = info(path)
    out: dict[str, Any] = {"fixes": len(stamp_err)}
    out["stamp_minus_truth"] = _stats(np.array(stamp_err))
    out["receipt_minus_truth"] = _stats(np.array(recv_delay))
    gnss_info = summary.gnss_stamping
    if gnss_info is not None:
        out["acq_info"] = {k: v for k, v in vars(gnss_info).items()}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--time", choices=("auto", "fix", "receipt"), default=None)
    parser.add_argument("--latency", type=float, default=0.0, help="gnss.latency_s")
    parser.add_argument("--disciplined", action="store_true")
    args = parser.parse_args()
    if args.disciplined:
        real = kernel_clock.read_kernel_clock()
        assert real is not None, "Linux only"
        fake = kernel_clock.KernelClock(**{**vars(real), "synchronised": True, "state": "ok"})
        kernel_clock.read_kernel_clock = lambda: fake  # type: ignore[assignment]
    with tempfile.TemporaryDirectory() as tmp:
        result = measure(Path(tmp), args.seconds, args.time, args.latency)
    run = {"time": args.time, "latency_s": args.latency, "disciplined": args.disciplined}
    print(json.dumps({"run": run, **result, "at": time.strftime("%H:%M:%S")}))


if __name__ == "__main__":
    main()
