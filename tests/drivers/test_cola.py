"""SICK CoLa codec and LMDscandata parser: the real LMS111 capture, and fuzzing.

The capture (``../shared/data/sick/20210302_lms111.pcapng.json``) is a CoLa-B session
between a host driver and a real LMS111: the framer, the parser and the encoder are
checked against its bytes, and the driver's start-up runs against a server that answers
each request with the LMS111's recorded answer.
"""

from __future__ import annotations

import math
import struct
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from acq.drivers.cola import ColaScanner, parse_url
from acq.drivers.cola_codec import (
    ArgReader,
    ColaFramer,
    Telegram,
    build,
    check_error,
    frame,
    unframe,
)
from acq.drivers.cola_scandata import ScanData, encode_scandata, parse_scandata
from acq.drivers.scanner import DeviceError, ProtocolError
from acq.sim.transport import TcpDeviceServer
from tests.wireshark_json import Packet, Stream, read_packets, reassemble, split_directions

CAPTURE = (
    Path(__file__).resolve().parents[3] / "shared" / "data" / "sick" / "20210302_lms111.pcapng.json"
)
REQUESTS = (b"sMN", b"sRN", b"sWN", b"sEN")


def _from_device(payload: bytes) -> bool | None:
    """The export has no addresses: direction from the command type (host requests are
    sMN/sRN/sWN/sEN); a payload that does not start a telegram continues its
    predecessor's direction."""
    if payload[:4] != b"\x02\x02\x02\x02":
        return None
    return payload[8:11] not in REQUESTS


@dataclass(frozen=True)
class Capture:
    """The session's packets and both directions' streams, TCP retransmissions dropped."""

    packets: dict[int, Packet]  # by element index
    host: Stream  # host to device
    device: Stream  # device to host


@pytest.fixture(scope="module")
def capture() -> Capture:
    if not CAPTURE.is_file():
        pytest.skip(f"{CAPTURE} is absent: the real LMS111 capture is needed")
    packets = read_packets(CAPTURE)
    to_device, from_device = split_directions(packets, from_server=_from_device)
    return Capture({p.index: p for p in packets}, reassemble(to_device), reassemble(from_device))


@pytest.fixture(scope="module")
def device_telegrams(capture: Capture) -> list[Telegram]:
    framer = ColaFramer("b")
    framer.feed(capture.device.data)
    items = list(framer.items())
    assert all(isinstance(t, Telegram) for t in items)
    assert framer.skipped == 0 and framer.pending == 0
    return [t for t in items if isinstance(t, Telegram)]


@pytest.fixture(scope="module")
def real_scans(device_telegrams: list[Telegram]) -> list[ScanData]:
    return [
        parse_scandata(t.raw)
        for t in device_telegrams
        if t.kind == "sSN" and t.name == "LMDscandata"
    ]


# --- the real capture -----------------------------------------------------------------


def test_capture_has_172_distinct_scans(capture: Capture, real_scans: list[ScanData]) -> None:
    # 3 scans and 3 answers (sRA field023, sRA LIDinputstate, sEA LIDinputstate) are
    # TCP retransmissions in the capture: exact repeats of a payload already kept.
    assert capture.host.dropped == ()
    repeats = [capture.packets[i].payload for i in capture.device.dropped]
    assert len(repeats) == 6
    pieces = capture.device.pieces()
    assert all(r in pieces for r in repeats)
    names = sorted(b" ".join(r[8:].split(b" ")[:2]) for r in repeats)
    assert (
        names
        == [b"sEA LIDinputstate", b"sRA LIDinputstate", b"sRA field023"] + [b"sSN LMDscandata"] * 3
    )
    scans = [p for p in pieces if p[8:23] == b"sSN LMDscandata"]
    assert len(scans) == 172 and len(set(scans)) == 172
    assert len(real_scans) == 172
    counters = [s.scan_counter for s in real_scans]
    assert counters == list(range(4, 176))
    tele = np.diff([s.telegram_counter for s in real_scans]) % 65536
    assert (tele >= 1).all()  # the telegram counter also counts other telegrams


def test_capture_geometry_and_timing(real_scans: list[ScanData]) -> None:
    for s in real_scans:
        assert s.version == 1 and s.n_points == 541
        (d,) = s.channels16
        assert d.name == "DIST1" and d.scale == 1.0 and d.offset == 0.0
        assert d.start_angle == -450000 and d.step == 5000  # SICK: -45° .. +225°, 0.5°
        assert not s.channels8 and not s.encoders
        assert s.scan_frequency == 5000 and s.scan_period == pytest.approx(0.02)
        assert s.timestamp is not None and s.position is None and s.event is None
    s = real_scans[0]
    assert math.degrees(s.angle_min) == pytest.approx(-135.0)
    angle_max = s.angle_min + s.angle_increment * (s.n_points - 1)
    assert math.degrees(angle_max) == pytest.approx(135.0)
    assert s.time_increment == pytest.approx(0.02 * 0.5 / 360, rel=1e-6)
    starts = np.array([x.time_since_startup for x in real_scans], dtype=np.int64)
    tx = np.array([x.time_of_transmission for x in real_scans], dtype=np.int64)
    rate = 1e6 / np.diff(starts).mean()
    assert 49.5 < rate < 49.9  # nominal 50 Hz; the µs counters give ~49.7 Hz
    assert ((tx - starts) > 0).all() and ((tx - starts) < 20000).all()
    r = s.ranges()
    assert r.dtype == np.float32 and r.shape == (541,)
    raw = s.channels16[0].data
    assert np.array_equal(np.isinf(r), raw == 0)
    assert np.allclose(r[raw > 0], raw[raw > 0] / 1000.0)


def test_capture_encode_roundtrip(real_scans: list[ScanData]) -> None:
    """The encoder reproduces the LMS111's bytes exactly; CoLa-A keeps every value."""
    for s in real_scans:
        assert frame(encode_scandata(s, True), True) == s.raw
    for s in real_scans[:20]:
        a = parse_scandata(frame(encode_scandata(s, False), False))
        assert not a.binary
        assert np.array_equal(a.channels16[0].data, s.channels16[0].data)
        for f in ("scan_counter", "telegram_counter", "time_since_startup", "timestamp"):
            assert getattr(a, f) == getattr(s, f)
        assert a.angle_min == s.angle_min


def test_capture_chunked_stream(capture: Capture, device_telegrams: list[Telegram]) -> None:
    stream = capture.device.data
    rng = np.random.default_rng(1)
    framer = ColaFramer()
    got: list[bytes] = []
    pos = 0
    while pos < len(stream):
        n = int(rng.integers(1, 700))
        framer.feed(stream[pos : pos + n])
        pos += n
        while (t := framer.pop()) is not None:
            got.append(t.raw)
    assert got == [t.raw for t in device_telegrams]


def test_capture_control_answers(device_telegrams: list[Telegram]) -> None:
    by = {(t.kind, t.name): t for t in device_telegrams}
    assert by["sAN", "SetAccessMode"].reader().u8() == 1
    assert by["sRA", "FirmwareVersion"].reader().string().strip() == "V1.80.2"
    r = by["sRA", "LMPoutputRange"].reader()
    assert (r.u16(), r.u32(), r.i32(), r.i32()) == (1, 5000, -449997, 2249997)
    assert by["sAN", "LMCstartmeas"].reader().u8() == 0
    assert by["sAN", "Run"].reader().u8() == 1
    assert by["sEA", "LMDscandata"].reader().u8() == 1
    assert by["sRA", "SCdevicestate"].reader().u8() == 0  # while it is measuring
    assert by["sWA", "EIHstCola"].payload == b"sWA EIHstCola "


def test_capture_requests_match_our_encoding(capture: Capture) -> None:
    """Our request builder gives the bytes the recorded host driver sent."""
    sent = set(capture.host.pieces())
    ours = [
        build("sMN", "SetAccessMode", [("u8", 3), ("u32", 0xF4724744)], binary=True),
        build("sRN", "FirmwareVersion", binary=True),
        build("sRN", "LMPoutputRange", binary=True),
        build("sMN", "LMCstartmeas", binary=True),
        build("sMN", "Run", binary=True),
        build("sEN", "LMDscandata", [("u8", 1)], binary=True),
        build("sWN", "EIHstCola", [("u8", 1)], binary=True),
    ]
    for payload in ours:
        assert frame(payload, True) in sent


class ReplayDevice:
    """Answers each request with the LMS111's recorded answer; unknown requests get
    ``sFA`` (unknown index). After ``sEN LMDscandata 1`` it sends the recorded scans."""

    def __init__(self, host: list[bytes], device: list[bytes]) -> None:
        self.answers: dict[bytes, bytes] = {}
        framer = ColaFramer()
        for payload in host:
            framer.feed(payload)
        requests = [t for t in framer.items() if isinstance(t, Telegram)]
        framer.feed(b"".join(device))
        answers = [t for t in framer.items() if isinstance(t, Telegram)]
        self.scans = [t.raw for t in answers if t.kind == "sSN" and t.name == "LMDscandata"]
        want = {"sRN": "sRA", "sWN": "sWA", "sMN": "sAN", "sEN": "sEA"}
        for q in requests:
            for a in answers:
                if a.kind == want[q.kind] and a.name == q.name:
                    self.answers.setdefault(q.payload, a.raw)
                    break
        self.framer = ColaFramer()
        self.unknown: list[bytes] = []
        self.queue: list[bytes] = []

    def handle(self, data: bytes, now: float) -> bytes:
        self.framer.feed(data)
        out = b""
        for t in self.framer.items():
            assert isinstance(t, Telegram)
            if t.payload in self.answers:
                out += self.answers[t.payload]
                if t.payload == b"sEN LMDscandata \x01":
                    self.queue = list(self.scans)
            else:
                self.unknown.append(t.payload)
                out += frame(b"sFA \x00\x03", True)
        return out

    def poll(self, now: float) -> bytes:
        out, self.queue = b"".join(self.queue[:20]), self.queue[20:]
        return out

    def next_due(self, now: float) -> float | None:
        return now if self.queue else None

    def on_disconnect(self) -> None:
        self.queue = []

    def reboot(self, now: float) -> None:
        pass

    def corrupt_next(self) -> None:
        pass


def test_driver_against_recorded_lms111(capture: Capture) -> None:
    device = ReplayDevice(capture.host.pieces(), capture.device.pieces())
    with TcpDeviceServer(device) as server:
        scanner = ColaScanner(server.url, timeout=2.0)
        info = scanner.connect()
        assert info.firmware == "V1.80.2" and info.vendor == "SICK"
        assert info.extra["device_state"] == "SCdevicestate 0"
        g = scanner.geometry
        assert g is not None and g.n_points == 541
        assert math.degrees(g.angle_min) == pytest.approx(-135.0, abs=1e-3)
        assert math.degrees(g.angle_increment) == pytest.approx(0.5)
        scanner.start()
        scans = [scanner.read_scan() for _ in range(172)]
        scanner.close()
    assert [s.sequence for s in scans] == list(range(4, 176))
    g = scanner.geometry
    assert g.angle_min == pytest.approx(math.radians(-135.0), abs=1e-12)
    assert g.scan_period == pytest.approx(0.02) and g.time_increment > 0
    s = scans[0]
    assert s.ranges.size == 541 and s.intensities.size == 0
    assert s.device_ticks == (0x74287D59, 0x74288993)
    assert s.angle_min == pytest.approx(math.radians(-135.0))
    # Only the optional identity queries were unknown to the recording.
    names = {p.split(b" ")[1] for p in device.unknown}
    assert names <= {b"DeviceIdent", b"SerialNumber", b"STlms", b"LMPscancfg", b"LMDscandata"}


# --- codec units ----------------------------------------------------------------------


def test_parse_url() -> None:
    assert parse_url("tcp://192.168.0.1:2112") == ("192.168.0.1", 2112)
    assert parse_url("socket://127.0.0.1:2111") == ("127.0.0.1", 2111)
    assert parse_url("10.0.0.2:2112") == ("10.0.0.2", 2112)
    assert parse_url("10.0.0.2") == ("10.0.0.2", 2112)
    with pytest.raises(ValueError):
        parse_url("http://x:1")


def test_sfa_errors_map_to_device_error() -> None:
    with pytest.raises(DeviceError, match="access denied") as e:
        check_error(unframe(frame(b"sFA \x00\x01", True)))
    assert e.value.status == "sFA 1"
    with pytest.raises(DeviceError, match="unknown variable index"):
        check_error(unframe(frame(b"sFA 3", False)))
    check_error(unframe(frame(b"sRA FirmwareVersion 7 V1.80.2", False)))


def test_ascii_arguments() -> None:
    r = ArgReader(b"3 F4724744 +10 -5 FFF92230 B not defined 1 A 1F", False)
    assert r.u8() == 3 and r.u32() == 0xF4724744
    assert r.u16() == 10 and r.i16() == -5 and r.i32() == -450000
    assert r.string() == "not defined"
    assert list(r.array(3, "u16")) == [1, 10, 31]
    assert r.at_end()
    with pytest.raises(ProtocolError):
        ArgReader(b"1G", False).u16()
    with pytest.raises(ProtocolError):
        ArgReader(b"10000", False).u16()
    assert list(ArgReader(b"+1 2", False).array(2, "u16")) == [1, 2]


def test_framer_resyncs_after_garbage_and_bad_checksum(real_scans: list[ScanData]) -> None:
    good = real_scans[0].raw
    bad = bytearray(real_scans[1].raw)
    bad[-1] ^= 0xFF
    ascii_tg = frame(b"sRA FirmwareVersion 7 V1.80.2", False)
    framer = ColaFramer()
    framer.feed(b"\x00garbage\x02\x02" + good + bytes(bad) + b"\x03\x02x" + good + ascii_tg)
    items = list(framer.items())
    telegrams = [i.raw for i in items if isinstance(i, Telegram)]
    errors = [str(i) for i in items if isinstance(i, ProtocolError)]
    assert telegrams == [good, good, ascii_tg]
    assert len(errors) == 1 and "checksum" in errors[0]  # stray 02 02: skipped silently
    framer.feed(b"\x02\x02\x02\x02\xff\xff\xff\xff" + good)
    items = list(framer.items())
    assert isinstance(items[0], ProtocolError) and "length" in str(items[0])
    assert isinstance(items[-1], Telegram) and items[-1].raw == good


def test_scandata_optional_blocks_roundtrip(real_scans: list[ScanData]) -> None:
    """LMS5xx/TiM-style telegrams: encoders, 16- and 8-bit RSSI, name, comment, event."""
    s = real_scans[0]
    d = s.channels16[0]
    rssi = np.arange(541, dtype=np.uint16)
    from dataclasses import replace

    from acq.drivers.cola_scandata import Channel

    full = replace(
        s,
        encoders=((123456, 7),),
        channels16=(d, replace(d, name="RSSI1", data=rssi), replace(d, name="DIST2")),
        channels8=(replace(d, name="RSSI2", data=(rssi % 256).astype(np.uint8)),),
        position=(1.0, 2.0, 3.0, 0.0, 0.0, 0.5, 3.0, 1.0),
        name="LMS511 front",
        comment="a comment",
        event=("FDIN", 99, 123, -4500),
        raw=b"",
    )
    for binary in (True, False):
        p = parse_scandata(encode_scandata(full, binary), binary)
        assert p.encoders == full.encoders and p.position == full.position
        assert (p.name, p.comment, p.event) == (full.name, full.comment, full.event)
        assert np.array_equal(p.intensities(), rssi.astype(np.float32))
        assert np.array_equal(p.channel("RSSI2").data, rssi % 256)
        assert [c.name for c in p.channels] == ["DIST1", "RSSI1", "DIST2", "RSSI2"]
        assert isinstance(p.channels8[0], Channel)


# --- fuzzing --------------------------------------------------------------------------

FUZZ = settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


def _parse_any(data: bytes) -> None:
    try:
        parse_scandata(data)
    except ProtocolError:
        pass


@FUZZ
@given(st.binary(max_size=2000), st.sampled_from(["auto", "a", "b"]))
def test_fuzz_framer_random_bytes(data: bytes, mode: str) -> None:
    framer = ColaFramer(mode, max_length=4096)
    for i in range(0, len(data), 97):
        framer.feed(data[i : i + 97])
    for item in framer.items():
        assert isinstance(item, Telegram | ProtocolError)
        if isinstance(item, Telegram):
            _parse_any(item.payload)
            try:
                check_error(item)
            except DeviceError:
                pass


@FUZZ
@given(st.binary(max_size=600))
def test_fuzz_parser_random_payloads(data: bytes) -> None:
    _parse_any(b"sSN LMDscandata " + data)
    _parse_any(data)


@FUZZ
@given(data=st.data())
def test_fuzz_mutated_real_telegrams(real_scans: list[ScanData], data: st.DataObject) -> None:
    s = real_scans[data.draw(st.integers(0, len(real_scans) - 1))]
    binary = data.draw(st.booleans())
    payload = bytearray(encode_scandata(s, binary) if not binary else s.raw[8:-1])
    for _ in range(data.draw(st.integers(1, 6))):
        op = data.draw(st.sampled_from(["flip", "cut", "insert", "delete"]))
        pos = data.draw(st.integers(0, max(0, len(payload) - 1)))
        if op == "flip" and payload:
            payload[pos] = data.draw(st.integers(0, 255))
        elif op == "cut":
            del payload[pos:]
        elif op == "insert":
            payload[pos:pos] = data.draw(st.binary(min_size=1, max_size=8))
        elif payload:
            del payload[pos : pos + data.draw(st.integers(1, 8))]
    _parse_any(bytes(payload))
    _parse_any(frame(bytes(payload), binary))
    framer = ColaFramer()
    framer.feed(frame(bytes(payload), binary) + s.raw)
    items = list(framer.items())
    assert isinstance(items[-1], Telegram) and items[-1].raw == s.raw


def test_parse_throughput_smoke() -> None:
    """An LMS511 telegram (1141 points, DIST1 + RSSI1) parses quickly (bench/ times it)."""
    n = 1141
    from acq.drivers.cola_scandata import Channel

    dist = Channel("DIST1", 1.0, 0.0, -50000, 1667, np.arange(n, dtype=np.uint16))
    rssi = Channel("RSSI1", 1.0, 0.0, -50000, 1667, np.arange(n, dtype=np.uint16))
    sd = ScanData(
        "sSN", 1, 1, 1, (0, 0), 1, 1, 0, 0, (0, 0), (0, 0), 0, 2500, 540, (), (dist, rssi)
    )
    raw = frame(encode_scandata(sd, True), True)
    t = time.perf_counter()
    for _ in range(200):
        p = parse_scandata(raw)
    rate = 200 / (time.perf_counter() - t)
    assert p.n_points == n and rate > 500
    assert struct.unpack(">I", raw[4:8])[0] == len(raw) - 9
