"""Parse throughput of scanner telegrams on one core (issue 3).

A UTM-30LX ME telegram (1081 steps, range + intensity; the real capture in
../shared/data/hokuyo when present, else one from the simulated device) through
``acq.drivers.scip_codec.parse_scan``, and a simulated LMS511 LMDscandata telegram (1141
points, DIST1 + RSSI1) in CoLa-B and CoLa-A through ``acq.drivers.cola_scandata.parse_scandata``
plus the conversion to metres. One JSON line per telegram: median scans per second
over the repeats, against the target of 2,000 scans/s (50 times the fastest device).
"""

from __future__ import annotations

import json
import statistics
import struct
import time
from collections.abc import Callable
from pathlib import Path

from acq.drivers import cola_codec, cola_scandata, scip_codec
from acq.sim.cola_device import ColaDevice
from acq.sim.scanner_models import model
from acq.sim.scip_device import ScipDevice

HOKUYO = Path(__file__).resolve().parents[2] / "shared" / "data" / "hokuyo"
REPEATS = 7
TARGET = 2000.0


def utm30lx_me() -> tuple[bytes, scip_codec.ScipParams, str]:
    """An ME telegram and the PP parameters: from the real capture, else simulated."""
    logr = HOKUYO / "example_utm_30lx.logr"
    if logr.is_file():
        data, i, chunks = logr.read_bytes(), 0, []
        while i < len(data):
            n = struct.unpack(">I", data[i + 8 : i + 12])[0]
            chunks.append(data[i + 12 : i + 12 + n])
            i += 12 + n
        blocks = [b + b"\n\n" for b in b"".join(chunks).split(b"\n\n") if b]
        pp = next(b for b in blocks if b.startswith(b"PP\n"))
        me = next(b for b in blocks if b.startswith(b"ME") and b.split(b"\n")[1][:2] == b"99")
        info = scip_codec.parse_info(scip_codec.parse_reply(pp, info=True))
        return me, scip_codec.ScipParams.from_info(info), "real capture"
    m = model("utm-30lx")
    dev = ScipDevice(m)
    now = time.monotonic()
    dev.handle(b"ME0000108001000\n", now)
    out = dev.poll(now + 0.2)
    me = next(b + b"\n\n" for b in out.split(b"\n\n") if b.split(b"\n")[1][:2] == b"99")
    params = scip_codec.ScipParams(m.product, 23, 60000, m.ares, m.amin, m.amax, m.afrt, m.rpm)
    return me, params, "simulated"


def lms511_scandata(binary: bool) -> bytes:
    """One streamed LMDscandata payload of the simulated LMS511."""
    dev = ColaDevice(model("lms511"), protocol="cola-b" if binary else "cola-a")
    now = time.monotonic()
    requests = [
        cola_codec.build("sMN", "SetAccessMode", [("u8", 3), ("u32", 0xF4724744)], binary=binary),
        cola_codec.build("sMN", "LMCstartmeas", binary=binary),
        cola_codec.build("sEN", "LMDscandata", [("u8", 1)], binary=binary),
    ]
    for req in requests:
        dev.handle(cola_codec.frame(req, binary), now)
    framer = cola_codec.ColaFramer()
    framer.feed(dev.poll(now + 1.0))
    for tg in framer.items():
        if isinstance(tg, cola_codec.Telegram) and tg.name == "LMDscandata":
            return tg.payload
    raise RuntimeError("the simulated LMS511 sent no scan")


def rate(fn: Callable[[], object], calls: int) -> tuple[float, float]:
    """(median, min) calls per second over REPEATS repeats after a warm-up."""
    for _ in range(calls // 10 + 1):
        fn()
    rates = []
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        rates.append(calls / (time.perf_counter() - t0))
    return statistics.median(rates), min(rates)


def main() -> None:
    me, params, source = utm30lx_me()
    med, low = rate(lambda: scip_codec.parse_scan(me, params), 2000)
    print(json.dumps({"bench": "parse_scan", "device": "utm-30lx", "telegram": "ME",
                      "source": source, "bytes": len(me), "points": 1081,
                      "scans_per_s": round(med), "min_scans_per_s": round(low),
                      "target": TARGET, "repeats": REPEATS}))  # fmt: skip
    for binary in (True, False):
        payload = lms511_scandata(binary)

        def parse(payload: bytes = payload, binary: bool = binary) -> object:
            sd = cola_scandata.parse_scandata(payload, binary)
            return sd.ranges(), sd.intensities()

        med, low = rate(parse, 2000)
        print(json.dumps({"bench": "parse_scan", "device": "lms511",
                          "telegram": f"LMDscandata {'CoLa-B' if binary else 'CoLa-A'}",
                          "source": "simulated", "bytes": len(payload), "points": 1141,
                          "scans_per_s": round(med), "min_scans_per_s": round(low),
                          "target": TARGET, "repeats": REPEATS}))  # fmt: skip


if __name__ == "__main__":
    main()
