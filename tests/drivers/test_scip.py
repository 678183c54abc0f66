"""SCIP codec and driver: the real UTM-30LX capture, fuzzing, and the simulated devices."""

from __future__ import annotations

import math
import socket
import struct
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from acq.drivers import scip_codec as codec
from acq.drivers.scanner import (
    ConnectionLost,
    DeviceError,
    ProtocolError,
    ScannerError,
    ScanTimeout,
    scanner_for,
)
from acq.drivers.scip import ScipScanner
from acq.sim.scanner_models import MODELS
from acq.sim.scip_device import ScipDevice
from acq.sim.transport import PtyDeviceServer, TcpDeviceServer
from acq.time.clocksync import DeviceClock, latency_bounds

# drives simulated devices in real time: run alone (`make test`)
pytestmark = pytest.mark.realtime

HOKUYO = Path(__file__).resolve().parents[3] / "shared" / "data" / "hokuyo"
PARSE_ERRORS = (ProtocolError, DeviceError)


# --- the real capture ------------------------------------------------------------------


def _records(path: Path) -> list[tuple[float, bytes]]:
    data = path.read_bytes()
    out, i = [], 0
    while i < len(data):
        sec, usec, n = struct.unpack(">III", data[i : i + 12])
        out.append((sec + usec * 1e-6, data[i + 12 : i + 12 + n]))
        i += 12 + n
    assert i == len(data)
    return out


@pytest.fixture(scope="module")
def capture() -> dict[str, object]:
    logr, logw = HOKUYO / "example_utm_30lx.logr", HOKUYO / "example_utm_30lx.logw"
    if not (logr.is_file() and logw.is_file()):
        pytest.skip(f"{HOKUYO} lacks the real UTM-30LX capture (../shared/data/ is absent)")
    read = b"".join(b for _, b in _records(logr))
    written = b"".join(b for _, b in _records(logw))
    blocks = [b + b"\n\n" for b in read.split(b"\n\n") if b]
    return {"read": read, "written": written, "blocks": blocks}


def _block(capture: dict[str, object], echo: bytes) -> bytes:
    blocks = capture["blocks"]
    assert isinstance(blocks, list)
    return next(b for b in blocks if b.startswith(echo + b"\n"))


def _me_scan(capture: dict[str, object]) -> bytes:
    return _block(capture, b"ME0000108001100")


def test_capture_info_replies(capture: dict[str, object]) -> None:
    vv = codec.parse_info(codec.parse_reply(_block(capture, b"VV"), info=True))
    assert vv["PROD"] == "SOKUIKI Sensor TOP-URG UTM-30LX"
    assert vv["PROT"] == "SCIP 2.0" and vv["SERI"] == "00903971"
    pp = codec.ScipParams.from_info(
        codec.parse_info(codec.parse_reply(_block(capture, b"PP"), info=True))
    )
    assert (pp.dmin, pp.dmax, pp.ares, pp.amin, pp.amax, pp.afrt, pp.scan_rpm) == (
        23,
        60000,
        1440,
        0,
        1080,
        540,
        2400,
    )
    ii = codec.parse_info(codec.parse_reply(_block(capture, b"II"), info=True))
    assert codec.parse_time_field(ii["TIME"]) == 0x4991D0
    bm = codec.parse_reply(_block(capture, b"BM"))
    assert bm.status == "02"
    with pytest.raises(DeviceError, match="already on") as e:
        codec.raise_for_status("BM", bm.status)
    assert e.value.status == "02"


def test_capture_me_scan(capture: dict[str, object]) -> None:
    pp = codec.ScipParams.from_info(
        codec.parse_info(codec.parse_reply(_block(capture, b"PP"), info=True))
    )
    tele = _me_scan(capture)
    raw = codec.parse_scan_reply(tele)
    assert raw.timestamp == 4_821_609
    assert raw.ranges_mm.size == 1081 and raw.intensities is not None
    assert raw.intensities.size == 1081
    scan = codec.parse_scan(tele, pp, recv_ns=7)
    assert scan.size == 1081 and scan.intensities.size == 1081
    assert scan.device_ticks == (4_821_609,) and scan.raw == tele and scan.recv_ns == 7
    assert scan.angle_min == pytest.approx(-0.75 * math.pi)
    assert scan.angles()[-1] == pytest.approx(0.75 * math.pi)
    assert scan.time_increment == pytest.approx(0.025 / 1440)
    assert scan.scan_period == pytest.approx(0.05)  # ME...1..: every other scan
    assert scan.ranges[0] == pytest.approx(0.045)
    assert np.all(np.isfinite(scan.ranges) | np.isinf(scan.ranges) | np.isnan(scan.ranges))
    assert float(np.nanmax(scan.ranges[np.isfinite(scan.ranges)])) < 60.0
    assert scan.intensities[0] == 1809.0


class _ReplayServer:
    """TCP on 127.0.0.1 answering each command with the capture's reply to it.

    Commands the capture does not hold (QT at start-up) get a plain ``00`` reply. A scan
    command gets the recorded ME acknowledgement and scan with the echo line rewritten to
    the command sent (echo lines carry no checksum, so every checksummed byte is real).
    """

    def __init__(self, blocks: list[bytes]) -> None:
        self.replies: dict[bytes, bytes] = {}
        for b in blocks:
            self.replies.setdefault(b.split(b"\n", 1)[0], b)
        self.scan = next(b for b in blocks if b.startswith(b"ME") and b"\n99b\n" in b)
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.url = f"socket://127.0.0.1:{self.sock.getsockname()[1]}"
        self.received: list[bytes] = []
        threading.Thread(target=self._run, daemon=True).start()

    def _answer(self, line: bytes) -> bytes:
        if line in self.replies:
            return self.replies[line]
        if line[:2] == b"ME" and len(line) == 15:
            ack = line + b"\n00P\n\n"
            return ack + line + self.scan[self.scan.index(b"\n") :]
        return line + b"\n00P\n\n"

    def _run(self) -> None:
        conn, _ = self.sock.accept()
        buf = b""
        with conn:
            while True:
                data = conn.recv(4096)
                if not data:
                    return
                buf += data
                while b"\n" in buf:
                    line, buf = buf.split(b"\n", 1)
                    self.received.append(line)
                    conn.sendall(self._answer(line))

    def close(self) -> None:
        self.sock.close()


def test_capture_replay_driver_startup(capture: dict[str, object]) -> None:
    blocks = capture["blocks"]
    assert isinstance(blocks, list)
    server = _ReplayServer(blocks)
    try:
        drv = ScipScanner(server.url, intensity=True, timeout=2.0)
        info = drv.connect()
        assert info.vendor == "Hokuyo Automatic Co.,Ltd."
        assert info.model == "SOKUIKI Sensor TOP-URG UTM-30LX"
        assert info.serial == "00903971" and info.firmware.startswith("P.1.05")
        assert info.extra["device_ticks"] == str(0x4991D0)
        g = drv.geometry
        assert g is not None and g.n_points == 1081
        assert g.angle_min == pytest.approx(-0.75 * math.pi)
        assert g.scan_period == pytest.approx(0.025) and g.range_max == 60.0
        drv.start()
        scan = drv.read_scan()
        assert scan.device_ticks == (4_821_609,) and scan.size == 1081
        assert scan.intensities.size == 1081 and scan.sequence == 1
        assert server.received[:4] == [b"QT", b"VV", b"PP", b"II"]
        assert server.received[4] == b"ME0000108001000"
        drv.close()
    finally:
        server.close()


# --- codec units -----------------------------------------------------------------------


def test_encodings_round_trip() -> None:
    v = np.array([0, 1, 63, 64, 4095, 262143])
    assert codec.decode(codec.encode(v, 3), 3).tolist() == v.tolist()
    assert codec.decode(codec.encode(v[:5], 2), 2).tolist() == v[:5].tolist()
    assert codec.decode_int(b"1Dh") == 5432  # the SCIP spec's 3-character example
    assert codec.encode([16000000], 4) == b"m2@0"
    with pytest.raises(ProtocolError):
        codec.decode(b"0\x10", 2)
    assert codec.checksum(b"00") == ord("P") and codec.checksum(b"99") == ord("b")


def test_range_codes_rep117() -> None:
    mm = np.array([0, 1, 2, 3, 4, 5, 22, 23, 1000, 60000, 60001])
    r = codec.ranges_to_m(mm, 23, 60000, codec.UTM_ERRORS)
    assert np.isnan(r[0]) and r[1] == np.inf and r[2] == -np.inf and np.isnan(r[3])
    assert r[4] == -np.inf and np.isnan(r[5]) and np.isnan(r[6])
    assert r[7] == pytest.approx(0.023) and r[9] == pytest.approx(60.0) and r[10] == np.inf
    u = codec.ranges_to_m(np.array([0, 1, 7, 19, 20]), 20, 5600, codec.URG_ERRORS)
    assert u[0] == np.inf and u[1] == np.inf and np.isnan(u[2]) and np.isnan(u[3])
    assert codec.error_table_for("URG-04LX(Hokuyo)") is codec.URG_ERRORS


def test_status_messages() -> None:
    assert "undefined" in codec.status_message("ME", "0E")
    assert "out of range" in codec.status_message("MD", "04")
    assert "hardware" in codec.status_message("MD", "55")
    assert "adjust mode" in codec.status_message("TM1", "04")
    with pytest.raises(DeviceError) as e:
        codec.raise_for_status("GD0000108001", "10")
    assert e.value.status == "10" and "laser is off" in str(e.value)


# --- fuzzing: every parser gives a result or a ProtocolError/DeviceError ------------------

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
PARAMS = codec.ScipParams("UTM-30LX", 23, 60000, 1440, 0, 1080, 540, 2400)


def _all_parsers(data: bytes) -> None:
    for fn in (
        lambda: codec.parse_reply(data),
        lambda: codec.parse_info(codec.parse_reply(data, info=True)),
        lambda: codec.parse_scan_reply(data),
        lambda: codec.parse_scan(data, PARAMS),
        lambda: codec.parse_scan_echo(data.split(b"\n")[0]),
        lambda: codec.decode(data, 3),
        lambda: codec.parse_time_field(data.decode("latin-1")),
    ):
        try:
            fn()
        except PARSE_ERRORS:
            pass


@FUZZ
@given(st.binary(max_size=400))
def test_fuzz_random_bytes(data: bytes) -> None:
    _all_parsers(data)
    _all_parsers(data + b"\n\n")
    _all_parsers(b"MD0000000301000\n99b\n" + data + b"\n\n")


@FUZZ
@given(st.data())
def test_fuzz_mutated_real_telegrams(capture: dict[str, object], data: st.DataObject) -> None:
    blocks = capture["blocks"]
    assert isinstance(blocks, list)
    base = bytearray(data.draw(st.sampled_from(blocks)))
    for _ in range(data.draw(st.integers(1, 4))):
        op = data.draw(st.sampled_from(["flip", "delete", "insert", "truncate"]))
        i = data.draw(st.integers(0, len(base) - 1))
        if op == "flip":
            base[i] = data.draw(st.integers(0, 255))
        elif op == "delete":
            del base[i]
        elif op == "insert":
            base[i:i] = data.draw(st.binary(min_size=1, max_size=8))
        else:
            del base[i:]
        if not base:
            base = bytearray(b"\n")
    _all_parsers(bytes(base))


@FUZZ
@given(st.lists(st.integers(0, 262143), min_size=1, max_size=40), st.data())
def test_fuzz_multi_echo_round_trip(values: list[int], data: st.DataObject) -> None:
    n = len(values)
    payload = bytearray()
    echoes = []
    for v in values:
        k = data.draw(st.integers(0, 2))
        extra = [data.draw(st.integers(0, 262143)) for _ in range(k)]
        echoes.append([v, *extra])
        payload += codec.encode([v], 3) + b"".join(b"&" + codec.encode([e], 3) for e in extra)
    tsb = codec.encode([123], 4)
    tele = (
        f"ND0000{n - 1:04d}01000\n99b\n".encode()
        + tsb
        + bytes([codec.checksum(tsb)])
        + b"\n"
        + codec.encode_lines(bytes(payload))
        + b"\n"
    )
    raw = codec.parse_scan_reply(tele)
    assert raw.echoes_mm is not None
    for i, ech in enumerate(echoes):
        assert raw.echoes_mm[i, : len(ech)].tolist() == ech
        assert (raw.echoes_mm[i, len(ech) :] == -1).all()


class _FakeSerial:
    """Serves fixed bytes in small pieces, then reports a closed link."""

    def __init__(self, data: bytes, step: int) -> None:
        self.data, self.step = data, max(step, 1)

    @property
    def in_waiting(self) -> int:
        return min(len(self.data), self.step)

    def read(self, n: int) -> bytes:
        if not self.data:
            import serial

            raise serial.SerialException("device disconnected")
        out, self.data = self.data[:n], self.data[n:]
        return out

    def write(self, data: bytes) -> int:
        return len(data)


@FUZZ
@given(st.binary(max_size=300), st.integers(1, 50))
def test_fuzz_driver_stream(data: bytes, step: int) -> None:
    drv = ScipScanner("socket://127.0.0.1:1", timeout=0.05)
    drv.params = PARAMS
    drv._stream = codec.ScanEcho("MD", 0, 3, 1, 0, 0)
    drv._prefix = drv._stream.prefix()
    drv._ser = _FakeSerial(data, step)  # type: ignore[assignment]
    for _ in range(50):
        try:
            drv.read_scan()
        except (ProtocolError, DeviceError):
            continue
        except (ConnectionLost, ScanTimeout):
            break


# --- the driver against the simulated devices ----------------------------------------------

CASES = [
    ("utm-30lx", "tcp"),
    ("utm-30lx", "pty"),
    ("urg-04lx", "tcp"),
    ("urg-04lx", "pty"),
    ("ust-10lx", "tcp"),
]
_DEVICES: dict[str, ScipDevice] = {}


def _device(name: str) -> ScipDevice:
    if name not in _DEVICES:
        _DEVICES[name] = ScipDevice(MODELS[name])
    dev = _DEVICES[name]
    dev.on_disconnect()
    return dev


def _server(dev: ScipDevice, kind: str) -> TcpDeviceServer | PtyDeviceServer:
    return (TcpDeviceServer(dev) if kind == "tcp" else PtyDeviceServer(dev)).start()


@pytest.fixture
def served(request: pytest.FixtureRequest) -> Iterator[tuple[ScipDevice, str, object]]:
    name, kind = request.param
    dev = _device(name)
    srv = _server(dev, kind)
    try:
        yield dev, srv.url, srv
    finally:
        srv.close()


def _expected_m(dev: ScipDevice, mm: np.ndarray) -> np.ndarray:
    return codec.ranges_to_m(mm, dev.dmin, dev.dmax, codec.error_table_for(dev.model.name))


def _check_scan(dev: ScipDevice, scan, cmd: str) -> None:  # type: ignore[no-untyped-def]
    sent = {s.timestamp: s for s in dev.sent if s.command == cmd}
    assert scan.device_ticks[0] in sent, "timestamp is not one the device sent"
    s = sent[scan.device_ticks[0]]
    assert scan.device_ticks[0] == dev.clock.ticks(s.t_stamp)
    exp = _expected_m(dev, s.ranges_mm)
    np.testing.assert_array_equal(np.isnan(scan.ranges), np.isnan(exp))
    fin = np.isfinite(exp)
    np.testing.assert_array_equal(scan.ranges[~fin & ~np.isnan(exp)], exp[~fin & ~np.isnan(exp)])
    np.testing.assert_allclose(scan.ranges[fin], exp[fin], atol=1e-6)
    if s.intensities is not None:
        np.testing.assert_array_equal(scan.intensities, s.intensities.astype(np.float32))
    else:
        assert scan.intensities.size == 0


@pytest.mark.parametrize("served", CASES, indirect=True, ids=[f"{m}-{k}" for m, k in CASES])
def test_driver_against_sim(served: tuple[ScipDevice, str, object]) -> None:
    dev, url, _ = served
    m = dev.model
    drv = scanner_for("hokuyo", url, timeout=1.0, intensity=m.intensity)
    assert isinstance(drv, ScipScanner)
    with drv:
        info = drv.connect()
        assert (info.model, info.serial, info.firmware) == (m.product, m.serial, m.firmware)
        assert info.extra["VV.PROT"] == ("SCIP 2.2" if m.protocol == "scip2.2" else "SCIP 2.0")
        g = drv.geometry
        assert g is not None
        assert g.angle_min == pytest.approx(m.angle_min())
        assert g.angle_increment == pytest.approx(m.angle_increment())
        assert g.n_points == m.steps
        assert g.time_increment == pytest.approx(m.time_increment())
        assert g.scan_period == pytest.approx(m.scan_period)
        assert (g.range_min, g.range_max) == (pytest.approx(m.range_min), m.range_max)
        drv.start()
        cmd = "ME" if m.intensity else "MD"
        last = None
        for _ in range(4):
            scan = drv.read_scan()
            assert scan.size == m.steps and scan.angle_min == pytest.approx(m.angle_min())
            _check_scan(dev, scan, cmd)
            if last is not None:
                assert scan.sequence == last.sequence + 1 and scan.recv_ns >= last.recv_ns
                dt = (scan.device_ticks[0] - last.device_ticks[0]) / 1000
                assert dt == pytest.approx(round(dt / m.scan_period) * m.scan_period, abs=2e-3)
            last = scan
        drv.stop()
        lat = drv.measure_latency(5)
        assert 0 < lat.rtt_min <= lat.rtt_median <= lat.rtt_max < 0.5
        assert lat.one_way == pytest.approx(lat.rtt_min / 2)


@pytest.mark.parametrize("name", ["utm-30lx", "ust-10lx"])
def test_intensity_off_crop_cluster(name: str) -> None:
    dev = _device(name)
    with _server(dev, "tcp") as srv:
        drv = ScipScanner(srv.url, angle_min=-1.0, angle_max=0.5, cluster=3, timeout=1.0)
        drv.connect()
        p = drv.params
        assert p is not None
        start, end = drv.steps
        assert start == math.ceil(-1.0 / p.step_angle + p.afrt - 1e-6)
        assert end == math.floor(0.5 / p.step_angle + p.afrt + 1e-6)
        g = drv.geometry
        assert g is not None and g.n_points == -(-(end - start + 1) // 3)
        assert g.angle_min == pytest.approx(p.angle_of_step(start)) and g.angle_min >= -1.0
        assert g.angle_increment == pytest.approx(3 * p.step_angle)
        drv.start()
        for _ in range(2):
            scan = drv.read_scan()
            assert scan.size == g.n_points and scan.intensities.size == 0
            _check_scan(dev, scan, "MD")
            # the stamp refers to the step behind the sensor: point 0 (step ``start``)
            # was measured stamp_offset_s later
            sent = {s.timestamp: s for s in dev.sent}[scan.device_ticks[0]]
            step_dt = p.scan_period / p.ares
            assert sent.t_stamp + g.stamp_offset_s == pytest.approx(
                sent.t0 + start * step_dt, abs=1e-9
            )
            assert g.stamp_offset_s == pytest.approx((start - p.afrt + p.ares // 2) * step_dt)
        drv.close()


def test_multi_echo_single_two_char() -> None:
    dev = _device("utm-30lx")
    with _server(dev, "tcp") as srv:
        drv = ScipScanner(srv.url, multi_echo=True, intensity=True, timeout=1.0)
        drv.connect()
        drv.start()
        scan = drv.read_scan()
        sent = {s.timestamp: s for s in dev.sent if s.command == "NE"}[scan.device_ticks[0]]
        assert scan.extra_echoes is not None and scan.extra_intensities is not None
        for i, more in enumerate(sent.extra_mm):
            got = scan.extra_echoes[i]
            assert np.allclose(got[: len(more)], np.array(more) / 1000, atol=1e-6)
            assert np.isinf(got[len(more) :]).all()
        np.testing.assert_allclose(scan.ranges, _expected_m(dev, sent.ranges_mm), atol=1e-6)
        drv.stop()
        single = drv.single_scan()  # HE
        assert single.size == 1081 and single.extra_echoes is not None
        drv.close()
    dev = _device("urg-04lx")
    with _server(dev, "pty") as srv:
        drv = ScipScanner(srv.url, two_char=True, timeout=1.0)
        drv.connect()
        drv.start()
        scan = drv.read_scan()
        _check_scan(dev, scan, "MS")
        drv.stop()
        _check_scan(dev, drv.single_scan(), "GS")
        drv.close()


def test_unsupported_commands_and_errors() -> None:
    dev = _device("urg-04lx")
    with _server(dev, "tcp") as srv:
        drv = ScipScanner(srv.url, intensity=True, timeout=1.0)
        drv.connect()
        with pytest.raises(DeviceError) as e:
            drv.start()  # the URG-04LX has no ME
        assert e.value.status == "0E" and "undefined" in str(e.value)
        now = time.monotonic()
        assert dev.handle(b"MD0000999901000\n", now).startswith(b"MD0000999901000\n04")
        assert dev.handle(b"MD0100005001000\n", now).split(b"\n")[1][:2] == b"05"
        assert dev.handle(b"GD0044072501\n", now).split(b"\n")[1][:2] == b"10"
        assert dev.handle(b"XX\n", now) == b"XX\n0Ee\n\n"
        assert dev.handle(b"TM1\n", now).split(b"\n")[1][:2] == b"04"
        drv.close()


def test_scip22_ust_specifics() -> None:
    dev = _device("ust-10lx")
    now = time.monotonic()
    ii = codec.parse_info(codec.parse_reply(dev.handle(b"II\n", now), info=True))
    assert (
        len(ii["TIME"]) == 4 and abs(codec.parse_time_field(ii["TIME"]) - dev.clock.ticks(now)) < 5
    )
    assert codec.parse_reply(dev.handle(b"RB\n", now)).status == "01"
    assert codec.parse_reply(dev.handle(b"SS115200\n", now)).status == "0F"
    with _server(dev, "tcp") as srv:
        drv = ScipScanner(srv.url, timeout=1.0, baudrate=115200)  # ignored on Ethernet
        drv.connect()
        assert drv.protocol == "SCIP 2.2"
        assert abs(drv.device_time() - dev.clock.ticks(time.monotonic())) < 50
        drv.sleep()
        drv.start()
        _check_scan(dev, drv.read_scan(), "MD")
        drv.close()


def test_bad_info_checksum_quirk() -> None:
    dev = ScipDevice(MODELS["urg-04lx"], source=_device("urg-04lx").source, bad_info_checksum=True)
    with _server(dev, "pty") as srv:
        strict = ScipScanner(srv.url, timeout=1.0)
        with pytest.raises(ProtocolError, match="checksum"):
            strict.connect()
        strict.close()
        lenient = ScipScanner(srv.url, timeout=1.0, accept_bad_info_checksum=True, baudrate=115200)
        info = lenient.connect()
        assert info.firmware == MODELS["urg-04lx"].firmware and lenient.bad_info_checksums == 2
        assert dev.bitrate == 115200  # SS on a serial model
        lenient.close()


# --- faults ------------------------------------------------------------------------------


def _streaming(srv_dev: ScipDevice, srv, timeout: float = 1.0) -> ScipScanner:  # type: ignore[no-untyped-def]
    drv = ScipScanner(srv.url, intensity=True, timeout=2.0)  # a fresh source renders slowly
    drv.connect()
    drv.start()
    drv.read_scan()
    drv.timeout = timeout
    return drv


def test_fault_garbage_and_checksum() -> None:
    dev = _device("utm-30lx")
    with _server(dev, "tcp") as srv:
        drv = _streaming(dev, srv)
        for _ in range(3):
            srv.inject_garbage(200)
            got = None
            for _ in range(3):
                try:
                    got = drv.read_scan()
                    break
                except ProtocolError:
                    continue
            assert got is not None
            _check_scan(dev, got, "ME")
        srv.corrupt_checksum()
        with pytest.raises(ProtocolError, match="checksum"):
            for _ in range(3):
                drv.read_scan()
        for _ in range(2):
            _check_scan(dev, drv.read_scan(), "ME")
        drv.close()


def test_fault_stall_and_disconnect() -> None:
    dev = _device("utm-30lx")
    with _server(dev, "tcp") as srv:
        drv = _streaming(dev, srv, timeout=0.2)
        srv.stall(0.6)
        t = time.monotonic()
        with pytest.raises(ScanTimeout):
            for _ in range(40):
                drv.read_scan()
        assert time.monotonic() - t < 1.0
        time.sleep(0.5)
        _check_scan(dev, drv.read_scan(), "ME")
        srv.disconnect_mid_telegram()
        t = time.monotonic()
        with pytest.raises(ConnectionLost):
            for _ in range(40):
                drv.read_scan()
        assert time.monotonic() - t < 1.0
        drv.close()


def test_fault_pty_disconnect() -> None:
    dev = _device("urg-04lx")
    with _server(dev, "pty") as srv:
        drv = _streaming_plain(srv)
        srv.disconnect_mid_telegram()
        with pytest.raises(ConnectionLost):
            for _ in range(40):
                drv.read_scan()
        drv.close()


def _streaming_plain(srv) -> ScipScanner:  # type: ignore[no-untyped-def]
    drv = ScipScanner(srv.url, timeout=2.0)
    drv.connect()
    drv.start()
    drv.read_scan()
    drv.timeout = 1.0
    return drv


def test_errors_are_scanner_errors() -> None:
    drv = ScipScanner("socket://127.0.0.1:1", timeout=0.2)
    with pytest.raises(ScannerError):
        drv.connect()
    drv.close()


def test_time_queries_bound_the_scan_latency() -> None:
    # TM round trips say when the device read its clock; the one-way estimate of the
    # scan stamps carries a latency it cannot see (here mostly the time from the stamp,
    # behind the sensor, until the scan is sent after its last step)
    dev = _device("utm-30lx")
    with _server(dev, "tcp") as srv:
        drv = ScipScanner(srv.url, timeout=1.0)
        drv.connect()
        clock = DeviceClock(ScipScanner.tick_hz, ScipScanner.tick_bits)
        drv.start()
        scans = [drv.read_scan() for _ in range(120)]
        for scan in scans:
            clock.update(scan.device_ticks[0], scan.recv_ns)
        drv.stop()
        tm = drv.measure_latency(20)
        drv.close()
    sent = {s.timestamp: s for s in dev.sent}
    # the latency the clock carries: its stamp times minus the true ones (the simulated
    # device runs on time.monotonic()); with a drift estimate from 3 s of data it is not
    # quite constant, so take it at the time of the queries (it is linear in time)
    t_true = np.array([sent[s.device_ticks[0]].t_stamp for s in scans])
    carried = np.array([clock.to_host_ns(s.device_ticks[0]) * 1e-9 for s in scans]) - t_true
    t_query = float(np.median([a for a, _, _ in tm.samples])) * 1e-9
    truth = float(np.polyval(np.polyfit(t_true - t_true[0], carried, 1), t_query - t_true[0]))
    p = drv.params
    assert p is not None
    stamp_to_send = (drv.steps[1] + 1 - p.stamp_step) * p.scan_period / p.ares
    assert stamp_to_send - 0.001 < truth < stamp_to_send + 0.01
    lo, hi = latency_bounds(tm.samples, clock)
    assert lo <= truth <= hi
    assert hi - lo < 0.002 + tm.rtt_min + 1e-6  # two ticks and one round trip at most
    with pytest.raises(ValueError, match="disagree"):
        late = [(a + 50_000_000, t, b + 50_000_000) for a, t, b in tm.samples]
        latency_bounds([*tm.samples, *late], clock)
