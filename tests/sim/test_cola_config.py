"""The simulated SICK scanners honour what a client writes (raw telegrams, simulated time):
LMPoutputRange, LMDscandatacfg, mLMPsetscancfg and FREchoFilter as SICK's telegram
listings describe them, the start-up reads sick_scan_xd makes, and a replay that refuses
a configuration the log cannot serve."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pytest

from acq.drivers.cola_codec import ColaFramer, Telegram, build, frame, unframe
from acq.drivers.cola_scandata import ScanData, encode_scandata, parse_scandata
from acq.sim.cola_device import PASSWORDS, ColaDevice
from acq.sim.device_clock import SimClock
from acq.sim.replay_devices import ColaReplayDevice, ReplayClock, ReplayStream
from acq.sim.replay_records import MemoryRecords
from acq.sim.scan_source import StreetSource
from acq.sim.scanner_models import MODELS

T0 = 100.0  # simulated host time of the first request, s
Args = Sequence[tuple[str, object]]


def device(name: str, protocol: str = "cola-b") -> ColaDevice:
    model = MODELS[name]
    clock = SimClock(tick_hz=1e6, wrap_bits=32, epoch=0.0)
    source = StreetSource(model, t_origin=0.0)  # the same stretch of street every run
    return ColaDevice(model, source=source, clock=clock, protocol=protocol)


def ask(dev: ColaDevice, kind: str, name: str, args: Args = (), now: float = T0) -> Telegram:
    request = frame(build(kind, name, args, binary=dev.binary), dev.binary)
    return unframe(dev.handle(request, now))


def login(dev: ColaDevice) -> None:
    assert ask(dev, "sMN", "SetAccessMode", [("u8", 3), ("u32", PASSWORDS[3])]).args[-1:] in (
        b"\x01",
        b"1",
    )


def error_code(tg: Telegram) -> int:
    assert tg.kind == "sFA", tg.payload
    body = tg.payload[3:].lstrip(b" ")
    return int.from_bytes(body, "big") if tg.binary else int(body, 16)


def stream(dev: ColaDevice, seconds: float) -> list[ScanData]:
    """The scans streamed from T0 for ``seconds`` of simulated time."""
    assert ask(dev, "sEN", "LMDscandata", [("u8", 1)]).kind == "sEA"
    framer = ColaFramer()
    framer.feed(dev.poll(T0 + seconds))
    scans = []
    while (tg := framer.pop()) is not None:
        scans.append(parse_scandata(tg.payload, tg.binary))
    assert ask(dev, "sEN", "LMDscandata", [("u8", 0)], T0 + seconds).kind == "sEA"
    return scans


def sector(tg: Telegram) -> tuple[int, int, int, int]:
    r = tg.reader()
    return r.u16(), r.u32(), r.i32(), r.i32()


@pytest.mark.parametrize("protocol", ["cola-b", "cola-a"])
def test_the_output_range_cuts_the_scan(protocol: str) -> None:
    dev = device("lms111", protocol)
    written = [("u16", 1), ("u32", 5000), ("i32", 1000000), ("i32", 1900000)]
    assert error_code(ask(dev, "sWN", "LMPoutputRange", written)) == 10  # not logged in
    login(dev)
    assert ask(dev, "sWN", "LMPoutputRange", written).kind == "sWA"
    assert sector(ask(dev, "sRN", "LMPoutputRange")) == (1, 5000, 1000000, 1900000)
    scans = stream(dev, 0.1)
    assert len(scans) >= 4
    for sd in scans:
        dist = sd.channel("DIST1")
        assert dist is not None
        assert (dist.start_angle, dist.step, dist.data.size) == (1000000, 5000, 181)
    # the same beams as in the full scan (100 deg = beam 290 onwards), up to range noise
    full = device("lms111").scan_data(scans[0].scan_counter)[1].ranges[290:471]
    cut = scans[0].ranges()
    both = np.isfinite(full) & np.isfinite(cut)
    assert both.sum() > 90 and np.mean(np.isfinite(full) == np.isfinite(cut)) > 0.95
    assert np.abs(full[both] - cut[both]).max() < 0.1
    # sick_scan_xd writes the launch file's angles, a little inside the grid: snapped
    off_grid = [("u16", 1), ("u32", 5000), ("i32", -449997), ("i32", 2249997)]
    assert ask(dev, "sWN", "LMPoutputRange", off_grid).kind == "sWA"
    assert sector(ask(dev, "sRN", "LMPoutputRange")) == (1, 5000, -450000, 2250000)
    other_resolution = [("u16", 1), ("u32", 2500), ("i32", 0), ("i32", 900000)]
    assert error_code(ask(dev, "sWN", "LMPoutputRange", other_resolution)) == 4


def test_scandatacfg_chooses_channels_blocks_and_rate() -> None:
    dev = device("lms111")
    (default,) = stream(dev, 0.02)[:1]
    assert [c.name for c in default.channels] == ["DIST1"] and default.timestamp is not None
    login(dev)
    # channel 1, RSSI 16-bit, no encoder/position, name on, no comment, no time, every 2nd
    cfg = [("u8", v) for v in (1, 0, 1, 1, 0, 0, 0, 0, 1, 0, 0)] + [("u16", 2)]
    assert ask(dev, "sWN", "LMDscandatacfg", cfg).kind == "sWA"
    assert ask(dev, "sRN", "LMDscandatacfg").args == bytes([1, 0, 1, 1, 0, 0, 0, 0, 1, 0, 0, 0, 2])
    scans = stream(dev, 0.2)
    assert 4 <= len(scans) <= 6 and all(sd.scan_counter % 2 == 0 for sd in scans)
    for sd in scans:
        rssi = sd.channel("RSSI1")
        assert rssi is not None and rssi in sd.channels16 and rssi.data.dtype == ">u2"
        assert sd.name == "LMS1xx" and sd.timestamp is None
    cfg8 = [("u8", v) for v in (1, 0, 1, 0, 0, 0, 0, 0, 0, 0, 1)] + [("u16", 1)]
    assert ask(dev, "sWN", "LMDscandatacfg", cfg8).kind == "sWA"
    sd = stream(dev, 0.04)[0]
    rssi = sd.channel("RSSI1")
    assert rssi is not None and rssi in sd.channels8 and 0 < int(rssi.data.max()) <= 255
    assert sd.timestamp is not None and sd.name is None
    no_channel = [("u8", 0)] * 11 + [("u16", 1)]
    assert error_code(ask(dev, "sWN", "LMDscandatacfg", no_channel)) == 4


def test_the_lms511_sends_8_bit_rssi_by_default() -> None:
    sd = stream(device("lms511"), 0.05)[0]
    rssi = sd.channel("RSSI1")
    assert rssi is not None and rssi in sd.channels8 and rssi.data.size == 1141


def scancfg(frequency: int, resolution: int, start: int, stop: int) -> list[tuple[str, object]]:
    return [("u32", frequency), ("u16", 1), ("u32", resolution), ("i32", start), ("i32", stop)]


def set_scancfg(dev: ColaDevice, *cfg: int) -> tuple[int, int, int, int, int, int]:
    tg = ask(dev, "sMN", "mLMPsetscancfg", scancfg(*cfg))
    assert tg.kind == "sAN", tg.payload
    r = tg.reader()
    return r.u8(), r.u32(), r.u16(), r.u32(), r.i32(), r.i32()


def test_setscancfg_sets_frequency_and_resolution_the_model_allows() -> None:
    dev = device("lms111")
    assert error_code(ask(dev, "sMN", "mLMPsetscancfg", scancfg(2500, 2500, -450000, 2250000))) == 1
    login(dev)
    now = (5000, 1, 5000, -450000, 2250000)
    assert set_scancfg(dev, 3000, 5000, -450000, 2250000) == (1, *now)  # frequency
    assert set_scancfg(dev, 5000, 2500, -450000, 2250000) == (2, *now)  # resolution
    assert set_scancfg(dev, 3000, 1234, -450000, 2250000) == (3, *now)  # both
    assert set_scancfg(dev, 5000, 5000, -600000, 2250000) == (4, *now)  # area
    assert set_scancfg(dev, 2500, 2500, -450000, 2250000) == (0, 2500, 1, 2500, -450000, 2250000)
    r = ask(dev, "sRN", "LMPscancfg").reader()
    assert (r.u32(), r.u16(), r.u32(), r.i32(), r.i32()) == (2500, 1, 2500, -450000, 2250000)
    scans = stream(dev, 0.4)
    assert 9 <= len(scans) <= 10
    for sd in scans:
        dist = sd.channel("DIST1")
        assert dist is not None and (sd.scan_frequency, dist.data.size, dist.step) == (
            2500,
            1081,
            2500,
        )
        assert sd.time_increment == pytest.approx(0.04 / 1440, rel=1e-3)
    ticks = np.diff([sd.time_since_startup for sd in scans])
    assert np.all(ticks == 40000)
    tim = device("tim781")
    login(tim)
    assert set_scancfg(tim, 2500, 3333, -450000, 2250000)[0] == 1  # the TiM781 runs at 15 Hz
    lms5 = device("lms511")
    login(lms5)
    assert set_scancfg(lms5, 5000, 1667, -50000, 1850000)[0] == 2  # 0.1667 deg only at 25 Hz
    snapped = -50000 + 570 * 3333  # the stop on the beam grid
    assert set_scancfg(lms5, 5000, 3333, -50000, 1850000) == (0, 5000, 1, 3333, -50000, snapped)
    sd = stream(lms5, 0.1)[0]
    assert (sd.scan_frequency, sd.n_points) == (5000, 571)


def test_the_lms511_echo_filter_selects_one_or_all_echoes() -> None:
    dev = device("lms511")
    login(dev)
    all_channels = [("u8", v) for v in (0x1F, 0, 1, 0, 0, 0, 0, 0, 0, 0, 1)] + [("u16", 1)]
    assert ask(dev, "sWN", "LMDscandatacfg", all_channels).kind == "sWA"
    assert len(stream(dev, 0.05)[0].distance_channels()) == 1  # first echo only
    assert ask(dev, "sWN", "FREchoFilter", [("u8", 1)]).kind == "sWA"
    assert ask(dev, "sRN", "FREchoFilter").args == b"\x01"
    sd = stream(dev, 0.05)[0]
    assert [c.name for c in sd.channels8] == [f"RSSI{e}" for e in range(1, 6)]
    assert [c.name for c in sd.distance_channels()] == [f"DIST{e}" for e in range(1, 6)]
    assert not any(c.data.any() for c in sd.distance_channels()[1:])  # one surface, one echo
    assert ask(dev, "sWN", "FREchoFilter", [("u8", 2)]).kind == "sWA"
    assert len(stream(dev, 0.05)[0].distance_channels()) == 1
    assert error_code(ask(dev, "sWN", "FREchoFilter", [("u8", 3)])) == 4
    lms1 = device("lms111")
    login(lms1)
    assert error_code(ask(lms1, "sWN", "FREchoFilter", [("u8", 1)])) == 3  # LMS5xx only


def test_start_up_reads_as_the_real_lms111_answers() -> None:
    dev = device("lms111")
    assert ask(dev, "sRN", "SCdevicestate").args == b"\x01"
    login(dev)
    assert ask(dev, "sRN", "SCdevicestate").args == b"\x00"  # busy while configured
    assert ask(dev, "sMN", "Run").kind == "sAN"
    assert ask(dev, "sRN", "SCdevicestate").args == b"\x01"  # ready after Run
    # the capture's unused field, its I/O state and an event subscription, byte for byte
    unused = "3f8000000000000000001388fff9223002000000000000000000000100000000"
    assert ask(dev, "sRN", "field003").args == bytes.fromhex(unused)
    assert ask(dev, "sRN", "field029").args == b"\x00"
    assert error_code(ask(dev, "sRN", "field030")) == 3
    assert ask(dev, "sRN", "LIDinputstate").args == bytes.fromhex("000100000000020202020000")
    assert ask(dev, "sEN", "LFErec", [("u8", 1)]).args == b"\x01"
    assert ask(dev, "sRN", "LocationName").reader().string() == "not defined"
    assert ask(dev, "sRN", "ODpwrc").reader().u32() >= 1
    assert ask(dev, "sRN", "ODoprh").kind == "sRA"
    tim = device("tim781")
    assert ask(tim, "sRN", "field047").args[8:16] == bytes.fromhex("00000d05fff92230")
    r = ask(tim, "sRN", "LFErec").reader()
    assert r.u16() == 3 and r.u16() == 0 and r.u8() == 1  # three fields, indexed from 1


def replay_of(name: str, data: list[bytes], reports: list[str]) -> ColaReplayDevice:
    """A replayed ``name`` serving ``data`` (framed LMDscandata telegrams, 20 ms apart)."""
    model = MODELS[name]
    info = {"model": model.product, "firmware": model.firmware, "serial": model.serial}
    geometry = {
        "angle_min": model.angle_min(),
        "angle_increment": model.angle_increment(),
        "n_points": model.n_points,
        "scan_period": model.scan_period,
        "range_min": model.range_min,
        "range_max": model.range_max,
    }
    times = [int(k * 0.02e9) for k in range(len(data))]
    stream_ = ReplayStream(name, MemoryRecords(times, data), ReplayClock())
    return ColaReplayDevice(stream_, info, geometry, report=reports.append)


def test_a_replay_refuses_a_configuration_it_did_not_record() -> None:
    sim = device("lms111")
    data = [frame(encode_scandata(sim.scan_data(k)[0], True), True) for k in range(5)]
    reports: list[str] = []
    dev = replay_of("lms111", data, reports)
    login(dev)
    half = [("u16", 1), ("u32", 5000), ("i32", 0), ("i32", 900000)]
    assert ask(dev, "sWN", "LMPoutputRange", half).kind == "sWA"
    assert error_code(ask(dev, "sEN", "LMDscandata", [("u8", 1)])) == 4
    assert len(reports) == 1 and "181 points" in reports[0] and "541 points" in reports[0]
    full = [("u16", 1), ("u32", 5000), ("i32", -450000), ("i32", 2250000)]
    assert ask(dev, "sWN", "LMPoutputRange", full).kind == "sWA"
    assert ask(dev, "sEN", "LMDscandata", [("u8", 1)]).kind == "sEA"


def test_a_replay_switched_to_cola_b_sends_the_recorded_cola_a_scans_in_it() -> None:
    sim = device("tim781", "cola-a")
    recorded = [sim.scan_data(k)[0] for k in range(5)]
    data = [frame(encode_scandata(sd, False), False) for sd in recorded]
    reports: list[str] = []
    dev = replay_of("tim781", data, reports)
    assert dev.protocol == "cola-a"
    login(dev)
    assert ask(dev, "sWN", "EIHstCola", [("u8", 1)]).kind == "sWA"
    assert dev.protocol == "cola-b"
    assert ask(dev, "sEN", "LMDscandata", [("u8", 1)]).kind == "sEA"
    framer = ColaFramer()
    framer.feed(dev.poll(T0 + 10.0))
    served = []
    while (tg := framer.pop()) is not None:
        assert tg.binary
        served.append(parse_scandata(tg.payload, True))
    assert len(served) == len(recorded) and not reports
    for got, sent in zip(served, recorded, strict=True):
        assert (got.scan_counter, got.time_since_startup) == (
            sent.scan_counter,
            sent.time_since_startup,
        )
        assert np.array_equal(got.ranges(), sent.ranges())
        assert np.array_equal(got.intensities(), sent.intensities())
