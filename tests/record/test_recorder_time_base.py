"""The recorder's time base: one ``/acq/timebase`` reading a second, the GNSS
receiver's time against the host clock in it, and the ``time_base`` metadata; with the
simulated receiver's UTC 20 ms ahead of the host's, ``acq info`` warns. Nothing mocked:
the simulated receiver on a pty (and a scanner, which a configuration needs), the
host's own clock sources (absent ones recorded as absent)."""

from __future__ import annotations

import inspect
import itertools
import statistics
import time
from pathlib import Path

import pytest
import yaml

from acq.log import info, read_metadata
from acq.log.summary import format_info
from acq.record import config as configfile
from acq.record.recorder import Recorder
from acq.sim.nmea_device import NmeaDevice, NmeaPtyServer
from acq.sim.scanner_models import MODELS
from acq.sim.scip_device import ScipDevice
from acq.sim.transport import TcpDeviceServer
from acq.time.clocksync import DeviceClock
from tests.sim_rig import read_log

pytestmark = pytest.mark.realtime  # drives a simulated device in real time

SECONDS = 3.5
GNSS_LATENCY_S = 0.040  # the simulated receiver's constant delay (3 ms jitter on top)
GNSS_AHEAD_S = 0.020  # the receiver's UTC ahead of the host's
# the recorder's GNSS clock: the bound on its line's drift (DeviceClock's default)
DRIFT_BOUND = inspect.signature(DeviceClock).parameters["max_drift_ppm"].default * 1e-6


def test_one_time_base_reading_a_second_with_gnss_against_the_host(tmp_path: Path) -> None:
    utc_offset = time.time() - time.monotonic() + GNSS_AHEAD_S
    server = NmeaPtyServer(NmeaDevice(utc_offset_s=utc_offset, latency_s=GNSS_LATENCY_S)).start()
    scanner = TcpDeviceServer(ScipDevice(MODELS["utm-30lx"])).start()
    try:
        data = {
            "version": 1,
            "scanners": [{"name": "laser", "driver": "hokuyo", "url": scanner.url}],
            "gnss": {"url": server.url, "baudrate": 115200, "latency_s": GNSS_LATENCY_S},
            "output": {"dir": str(tmp_path / "logs")},
        }
        (tmp_path / "rig.yaml").write_text(yaml.safe_dump(data))
        cfg = configfile.load(tmp_path / "rig.yaml")
        assert Recorder(cfg, duration_s=SECONDS).run() == 0
    finally:
        server.close()
        scanner.close()
    (path,) = sorted((tmp_path / "logs").glob("*.mcap"))
    log = read_log(path)
    readings = log["/acq/timebase"]
    assert SECONDS - 1.5 <= len(readings) <= SECONDS + 1, len(readings)
    times = [t for t, _, _ in readings]
    assert all(0.8e9 < b - a < 1.3e9 for a, b in itertools.pairwise(times)), times
    last = readings[-1][2]
    absent = "; ".join(last.absent)  # type: ignore[attr-defined]
    assert last.HasField("kernel") or "kernel" in absent  # type: ignore[attr-defined]
    assert last.HasField("chrony") or "chrony: " in absent  # type: ignore[attr-defined]
    gnss = last.gnss  # type: ignore[attr-defined]
    assert gnss.latency_s == GNSS_LATENCY_S and 0 <= gnss.fix_age_s < 0.5
    # host minus GNSS: -20 ms, plus the least delay beyond latency_s the recorder received
    # a fix with before the reading (the receiver's jitter, and on a loaded host its
    # lateness and the recorder's own wait for the pty: no recorder sees below that)
    timing = log["/acq/timing/gnss"]
    fixes = [(m.recv_ns, m.device_ticks[0] * 1e-6) for _, _, m in timing]  # type: ignore[attr-defined]
    expected = []
    for reading in (r for _, _, r in readings if r.HasField("gnss")):  # type: ignore[attr-defined]
        floor = min(recv * 1e-9 - (utc - utc_offset) - GNSS_LATENCY_S for recv, utc in fixes
                    if recv <= reading.monotonic_ns)  # type: ignore[attr-defined]  # fmt: skip
        # and what the host's UTC moved against its monotonic clock since the start (a
        # slewing clock: the receiver's UTC here is tied to the monotonic one)
        wall = (reading.realtime_ns - reading.monotonic_ns) * 1e-9  # type: ignore[attr-defined]
        slew = wall - (utc_offset - GNSS_AHEAD_S)
        expected.append(-GNSS_AHEAD_S + floor + slew)
        off = reading.gnss.host_minus_gnss_s - expected[-1]  # type: ignore[attr-defined]
        # the clock's line supports the receipts' lower envelope with a slope of 1 within
        # its drift bound: at the reading it may lie that much times the time since the
        # first fix below the least delay seen, or above it (a loaded host's floor rising)
        since = (reading.monotonic_ns - fixes[0][0]) * 1e-9  # type: ignore[attr-defined]
        tilt = DRIFT_BOUND * since
        assert -0.001 - tilt < off < 0.002 + tilt, (off, floor, slew, tilt)
    assert expected, "no reading with the receiver's time"
    meta = read_metadata(path)["time_base"]
    assert meta["utc_trusted"] == "no" and int(meta["records"]) == len(readings)
    assert "off GNSS time" in meta["warnings"]
    summary = info(path).host_clock
    assert summary is not None and summary.gnss_ms_median is not None
    assert summary.gnss_ms_median == pytest.approx(1e3 * statistics.median(expected), abs=2)
    assert "off GNSS time (median; limit 1 ms)" in format_info(info(path))
