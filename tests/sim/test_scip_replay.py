"""A replayed Hokuyo serves the recorded scans in the forms other clients ask for them
(urg_library, hokuyolx): single scans, another count or cluster field, distances without
the intensities, fewer steps; every value the recorded one; other data refused. Command
by command, without real time."""

from __future__ import annotations

import numpy as np
import pytest

from acq.drivers.scip_codec import RawScan, parse_reply, parse_scan_reply
from acq.sim.replay_devices import ReplayClock, ReplayStream, ScipReplayDevice
from acq.sim.replay_records import MemoryRecords
from acq.sim.scanner_models import MODELS
from acq.sim.scip_device import ScipDevice

RECORDED = b"ME0000108001000"
T = 100.0  # s, host time the client starts at


def recorded_telegrams(n: int = 8) -> list[bytes]:
    """``n`` telegrams of a simulated UST-10LX streaming ME, as a driver receives them."""
    dev = ScipDevice(MODELS["ust-10lx"])
    dev.handle(RECORDED + b"\n", 10.0)
    blocks = dev.poll(10.0 + (n + 1) * dev.period).split(b"\n\n")
    return [b + b"\n\n" for b in blocks[1 : n + 1]]  # after the 00 reply


Served = tuple[ScipReplayDevice, list[bytes], list[str]]  # the device, the log, its reports


@pytest.fixture
def replay() -> Served:
    data = recorded_telegrams()
    times = [1_000_000_000 + k * 25_000_000 for k in range(len(data))]
    stream = ReplayStream("laser", MemoryRecords(times, data), ReplayClock(lead_s=0.0))
    info = {"model": "UST-10LX", "extra": {"VV.PROT": "SCIP 2.2", "PP.MODL": "UST-10LX"}}
    params = {"dmin": 20, "dmax": 30000, "scan_rpm": 2400, "amin": 0, "amax": 1080,
              "afrt": 540, "ares": 1440}  # fmt: skip
    errors: list[str] = []
    return ScipReplayDevice(stream, info, params, errors.append), data, errors


def scans(out: bytes) -> list[RawScan]:
    return [parse_scan_reply(b + b"\n\n") for b in out.split(b"\n\n") if b]


def test_the_recorded_request_gets_the_recorded_bytes(replay: Served) -> None:
    dev, data, errors = replay
    assert parse_reply(dev.handle(RECORDED + b"\n", T)).status == "00"
    assert dev.poll(T + 1.0) == b"".join(data)
    assert not errors


def test_single_scans_come_from_the_recorded_stream(replay: Served) -> None:
    dev, data, errors = replay
    assert parse_reply(dev.handle(b"GE0000108000\n", T)).status == "10"  # laser off
    dev.handle(b"BM\n", T)
    (ge,) = scans(dev.handle(b"GE0000108000\n", T + 0.06))
    (gd,) = scans(dev.handle(b"GD0000108000\n", T + 0.06))
    rec = parse_scan_reply(data[2])  # the one received 50 ms into the log
    assert (ge.echo.command, ge.status, gd.echo.command, gd.status) == ("GE", "00", "GD", "00")
    assert ge.timestamp == gd.timestamp == rec.timestamp
    assert np.array_equal(ge.ranges_mm, rec.ranges_mm) and np.array_equal(
        gd.ranges_mm, rec.ranges_mm
    )
    assert rec.intensities is not None and np.array_equal(ge.intensities, rec.intensities)
    assert gd.intensities is None
    assert dev.handle(b"GD0000108000\n", T + 5.0) == b""  # after the log: silent
    assert not errors


def test_a_finite_count_of_distances_in_fewer_steps(replay: Served) -> None:
    dev, data, errors = replay
    assert parse_reply(dev.handle(b"MD0100020000003\n", T)).status == "00"
    got = scans(dev.poll(T + 1.0))
    recorded = [parse_scan_reply(d) for d in data[:3]]
    assert [s.echo.remaining for s in got] == [2, 1, 0]
    assert [s.timestamp for s in got] == [r.timestamp for r in recorded]
    for s, r in zip(got, recorded, strict=True):
        assert s.intensities is None and np.array_equal(s.ranges_mm, r.ranges_mm[100:201])
    assert dev.poll(T + 2.0) == b"" and not dev.laser
    assert not errors


@pytest.mark.parametrize(
    "request_",
    [b"ND0000108001000", b"MS0000108001000", b"ME0000108001100", b"ME0000108002000"],
)
def test_other_data_is_refused(replay: Served, request_: bytes) -> None:
    dev, _data, errors = replay
    assert parse_reply(dev.handle(request_ + b"\n", T)).status == "0E"
    assert len(errors) == 1 and request_.decode() in errors[0]
