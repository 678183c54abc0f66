"""The SICK driver against the simulated LMS111 / LMS511 / TiM781 over TCP, with faults."""

from __future__ import annotations

import time
from collections.abc import Iterator

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from acq.drivers.cola import ColaScanner
from acq.drivers.cola_codec import build, frame
from acq.drivers.scanner import ConnectionLost, DeviceError, ProtocolError, ScanTimeout
from acq.sim.cola_device import ColaDevice
from acq.sim.device_clock import SimClock
from acq.sim.scanner_models import MODELS
from acq.sim.transport import TcpDeviceServer

# drives simulated devices in real time: run alone (`make test`)
pytestmark = pytest.mark.realtime


@pytest.fixture
def lms111() -> Iterator[tuple[ColaDevice, TcpDeviceServer]]:
    device = ColaDevice(MODELS["lms111"])
    server = TcpDeviceServer(device).start()
    yield device, server
    server.close()


def _started(server: TcpDeviceServer, timeout: float = 2.0, **kw: object) -> ColaScanner:
    scanner = ColaScanner(server.url, timeout=timeout, **kw)  # type: ignore[arg-type]
    scanner.connect()
    scanner.start()
    return scanner


@pytest.mark.parametrize("protocol", ["cola-b", "cola-a"])
@pytest.mark.parametrize("name", ["lms111", "lms511", "tim781"])
def test_driver_reads_what_the_device_sent(name: str, protocol: str) -> None:
    model = MODELS[name]
    clock = SimClock(tick_hz=1e6, wrap_bits=32, drift_ppm=30.0, epoch=time.monotonic() - 3.0)
    device = ColaDevice(model, clock=clock, protocol=protocol)
    with TcpDeviceServer(device) as server:
        scanner = ColaScanner(server.url, protocol=protocol, timeout=3.0)
        info = scanner.connect()
        assert (info.vendor, info.model, info.serial) == ("SICK", model.product, model.serial)
        assert info.firmware == model.firmware and info.extra["protocol"] == protocol
        g = scanner.geometry
        assert g is not None and g.n_points == model.n_points
        assert g.angle_min == pytest.approx(model.angle_min(), abs=1e-9)
        assert g.angle_increment == pytest.approx(model.angle_increment(), abs=1e-6)
        assert g.scan_period == pytest.approx(model.scan_period)
        assert g.time_increment == pytest.approx(model.time_increment(), rel=2e-3)
        assert (g.range_min, g.range_max) == (model.range_min, model.range_max)
        scanner.start()
        scans = [scanner.read_scan() for _ in range(4)]
        scanner.stop()
        scanner.close()
    sent = {h.scan_counter: h for h in device.history}
    seqs = [s.sequence for s in scans]
    assert seqs[1:] == list(range(seqs[1], seqs[1] + 3))  # the first may precede a JIT pause
    for s in scans:
        h = sent[s.sequence]
        assert np.array_equal(s.ranges, h.ranges)  # mm on the wire, metres here
        assert s.device_ticks == h.ticks
        assert s.intensities.size == (model.n_points if model.intensity else 0)
        if model.intensity:
            assert np.array_equal(s.intensities, h.intensities)
        assert s.angle_min == pytest.approx(model.angle_min(), abs=1e-9)
        assert s.scan_period == pytest.approx(model.scan_period)
        assert s.recv_ns > 0 and s.raw[:1] == b"\x02"
    ticks = np.array([s.device_ticks[0] for s in scans[1:]], dtype=np.int64)
    expect = model.scan_period * 1e6 * (1 + 30e-6)
    assert np.allclose(np.diff(ticks), expect, atol=2)


def test_intensity_off_and_wrong_protocol() -> None:
    device = ColaDevice(MODELS["tim781"])
    with TcpDeviceServer(device) as server:
        scanner = _started(server, intensity=False)
        assert scanner.read_scan().intensities.size == 0
        scanner.close()
        wrong = ColaScanner(server.url, protocol="cola-a", timeout=1.0)
        with pytest.raises(ProtocolError, match="set protocol: cola-b"):
            wrong.connect()
        wrong.close()


def test_switch_to_cola_a_and_errors(lms111) -> None:
    device, server = lms111
    scanner = ColaScanner(server.url, timeout=2.0)
    scanner.connect()
    with pytest.raises(DeviceError, match="unknown variable index"):
        scanner.request("sRN", "NoSuchVariable")
    scanner.set_access_mode()
    scanner.request("sWN", "EIHstCola", (("u8", 0),))
    assert device.protocol == "cola-a"
    scanner.close()
    a = _started(server, protocol="cola-a")
    assert a.read_scan().ranges.size == 541
    a.close()
    bad = ColaScanner(server.url, protocol="cola-a", login=(3, 1234), timeout=2.0)
    with pytest.raises(DeviceError, match="SetAccessMode refused"):
        bad.connect()
    bad.close()


def test_garbage_mid_stream_resyncs(lms111) -> None:
    _device, server = lms111
    scanner = _started(server)
    scanner.read_scan()
    for _ in range(3):
        server.inject_garbage(300)
        s = scanner.read_scan()
        assert s.ranges.size == 541
    last = scanner.read_scan().sequence
    assert scanner.read_scan().sequence == (last + 1) % 65536
    scanner.close()


def test_bad_checksum_then_recovery(lms111) -> None:
    _device, server = lms111
    scanner = _started(server)
    scanner.read_scan()
    server.corrupt_checksum()
    errors = 0
    for _ in range(5):
        try:
            scanner.read_scan()
        except ProtocolError as exc:
            assert "checksum" in str(exc)
            errors += 1
            break
    assert errors == 1
    a, b = scanner.read_scan(), scanner.read_scan()
    assert b.sequence == (a.sequence + 1) % 65536
    scanner.close()


def test_stall_times_out_then_resumes(lms111) -> None:
    _device, server = lms111
    scanner = _started(server, timeout=0.25)
    scanner.read_scan()
    server.stall(0.8)
    t = time.monotonic()
    with pytest.raises(ScanTimeout):
        for _ in range(20):
            scanner.read_scan()
    assert time.monotonic() - t < 1.2
    deadline = time.monotonic() + 3
    while time.monotonic() < deadline:
        try:
            assert scanner.read_scan().ranges.size == 541
            break
        except ScanTimeout:
            continue
    else:
        pytest.fail("no scan after the stall")
    scanner.close()


def test_disconnect_mid_telegram(lms111) -> None:
    _device, server = lms111
    scanner = _started(server)
    scanner.read_scan()
    server.disconnect_mid_telegram()
    t = time.monotonic()
    with pytest.raises(ConnectionLost):
        for _ in range(20):
            scanner.read_scan()
    assert time.monotonic() - t < 1.5
    with pytest.raises(ConnectionLost):
        scanner.read_scan()
    scanner.close()
    scanner.close()
    again = _started(server)  # the device takes a new client
    assert again.read_scan().ranges.size == 541
    again.close()


def test_reboot_resets_clock_and_counters(lms111) -> None:
    _device, server = lms111
    scanner = _started(server)
    before = scanner.read_scan()
    server.reboot(0.2)
    with pytest.raises((ConnectionLost, ScanTimeout)):
        for _ in range(50):
            scanner.read_scan()
    scanner.close()
    time.sleep(0.3)
    again = _started(server)
    after = again.read_scan()
    again.close()
    assert after.device_ticks[0] < before.device_ticks[0]
    assert after.sequence < 200


def test_single_scan_poll_and_stop_laser(lms111) -> None:
    device, server = lms111
    scanner = ColaScanner(server.url, timeout=2.0, stop_laser=True)
    scanner.connect()
    r = scanner.request("sRN", "LMDscandata")
    assert r.u16() == 1  # the version field of a polled telegram
    scanner.start()
    scanner.read_scan()
    scanner.stop()
    assert not device.measuring and not device.streaming
    with pytest.raises(DeviceError, match="local condition"):
        scanner.request("sRN", "LMDscandata")
    scanner.close()


_FUZZ_DEVICE: list[ColaDevice] = []


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=400), st.booleans())
def test_fuzz_device_input(data: bytes, binary: bool) -> None:
    """Random and half-valid requests never break the simulated device."""
    if not _FUZZ_DEVICE:
        _FUZZ_DEVICE.append(ColaDevice(MODELS["lms111"]))
    device = _FUZZ_DEVICE[0]
    device.on_disconnect()
    now = time.monotonic()
    assert isinstance(device.handle(data, now), bytes)
    device.on_disconnect()
    out = device.handle(frame(build("sRN", "FirmwareVersion", binary=binary), binary), now)
    assert b"FirmwareVersion" in out
    assert isinstance(device.poll(now), bytes)
