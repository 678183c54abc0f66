"""NMEA 0183: the simulated receiver on a real pseudo-terminal -> the driver -> fixes
matching the truth; checksum errors and line noise typed and counted; reconnection
after the port goes away; the framer and the decoder fuzzed. Nothing is mocked."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from acq.drivers.errors import ConnectionLost
from acq.drivers.nmea import (
    MAX_LINE,
    LineFramer,
    NmeaChecksumError,
    NmeaDecoder,
    NmeaError,
    NmeaReceiver,
)
from acq.drivers.reconnect import Backoff, Relink
from acq.geometry.geodesy import WorldFrame
from acq.records import CovarianceType, Fix, Sentence
from acq.sim.nmea_device import DEFAULT_ORIGIN, NmeaDevice, NmeaPtyServer, sentence
from acq.sim.world import Trajectory

# drives simulated devices in real time: run alone (`make test`)
pytestmark = pytest.mark.realtime

CURVY = Trajectory(curve_amplitude=2.0, curve_wavelength=60.0)
GGA = b"$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47"
RMC = b"$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A"


@pytest.fixture
def receiver() -> Iterator[tuple[NmeaDevice, NmeaPtyServer]]:
    # the receiver's UTC is 3.7 s off the host's wall clock: nothing may depend on it
    device = NmeaDevice(CURVY, utc_offset_s=time.time() - time.monotonic() + 3.7)
    server = NmeaPtyServer(device).start()
    try:
        yield device, server
    finally:
        server.close()


def decode_all(lines: list[bytes], decoder: NmeaDecoder | None = None) -> list[Fix]:
    """Every fix the lines give, those the end of the stream flushes included."""
    decoder = decoder or NmeaDecoder()
    fixes = [decoder.decode(Sentence(i, line)) for i, line in enumerate(lines)]
    return [f for f in fixes if f is not None] + decoder.flush()


# --- the simulated receiver on a pty ---------------------------------------------------------


def test_fixes_from_the_simulated_receiver_match_the_truth(
    receiver: tuple[NmeaDevice, NmeaPtyServer],
) -> None:
    device, server = receiver
    with NmeaReceiver(server.url) as rx:
        info = rx.connect()
        rx.start()
        fixes = [rx.read_fix() for _ in range(25)]
    assert info.driver == "nmea" and info.extra["url"] == server.url
    truth = {round(t.utc_s, 2): t for t in device.truth}
    period = np.diff([f.utc_s for f in fixes])
    np.testing.assert_allclose(period, 0.1, atol=1e-6)  # 10 Hz, none lost
    for fix in fixes:
        t = truth[round(fix.utc_s, 2)]
        assert fix.utc_s == pytest.approx(t.utc_s, abs=1e-6)
        # ddmm.mmmmmmm: 1e-7 minute is 0.2 mm; altitude in mm; speed 0.001 kn; 0.01 deg
        assert fix.latitude == pytest.approx(t.latitude, abs=2e-9)
        assert fix.longitude == pytest.approx(t.longitude, abs=3e-9)
        assert fix.altitude == pytest.approx(t.altitude, abs=6e-4)
        assert fix.speed == pytest.approx(t.speed, abs=3e-4)
        assert fix.course == pytest.approx(t.course, abs=1e-4)
        assert (fix.quality, fix.satellites, fix.hdop) == (1, 14, 0.7)
        assert fix.geoid_separation == pytest.approx(44.6)
        # received after the fix instant: the receiver's latency and jitter
        delay = fix.recv_ns * 1e-9 - t.t
        assert device.latency_s <= delay < device.latency_s + 0.05
    # the truth itself: the antenna 1.9 m above the road, the road on the tangent plane
    lat0, lon0, msl0 = DEFAULT_ORIGIN
    first = device.truth_at(device.t_origin)
    east, north = CURVY.x0, CURVY.y0  # bearing 90: x east, y north
    (lat,), (lon,), (h,) = WorldFrame("enu", (lat0, lon0, msl0 + 44.6)).to_geodetic(
        [east, north, 1.9]
    )
    assert (first.latitude, first.longitude) == pytest.approx((lat, lon), abs=1e-12)
    assert first.altitude == pytest.approx(h, abs=1e-6)


def test_checksum_errors_and_noise_are_typed_and_counted(
    receiver: tuple[NmeaDevice, NmeaPtyServer],
) -> None:
    _, server = receiver
    with NmeaReceiver(server.url) as rx:
        rx.connect()
        rx.read_fix()
        server.corrupt_checksum()
        server.corrupt_checksum()
        server.inject_garbage(40)
        checksum_errors = other_errors = 0
        fixes: list[Fix] = []
        while len(fixes) < 8:
            try:
                s = rx.read_sentence()
                fix = rx.decode(s)
            except NmeaChecksumError as e:
                assert "checksum" in str(e)
                checksum_errors += 1
                continue
            except NmeaError:
                other_errors += 1  # garbage holding a LF makes a line of noise
                continue
            if fix is not None:
                fixes.append(fix)
    assert checksum_errors == 2
    assert other_errors <= 2 and rx.framer.noise_bytes >= 1
    assert np.all(np.diff([f.utc_s for f in fixes]) > 0)


def test_the_link_comes_back_after_the_port_goes_away(
    receiver: tuple[NmeaDevice, NmeaPtyServer],
) -> None:
    _, server = receiver
    rx = NmeaReceiver(server.url, timeout=1.0)
    events: list[str] = []
    link = Relink(rx, rx.read_sentence, backoff=Backoff(0.1, 0.5),
                  on_event=lambda e: events.append(e.kind))  # fmt: skip
    stop = threading.Event()
    received: list[Sentence] = []
    cut_at = 0.0
    for s in link.records(stop):
        received.append(s)
        if len(received) == 15:
            cut_at = time.monotonic()
            server.disconnect()  # the pty closes: a USB receiver unplugged and back
        if cut_at and s.recv_ns * 1e-9 > cut_at + 0.05 and len(received) > 30:
            break
    rx.close()
    assert events[0] == "connected" and "disconnected" in events
    assert events.count("connected") == 2
    assert time.monotonic() - cut_at < 3.0


def test_a_port_that_does_not_open_is_connection_lost() -> None:
    with pytest.raises(ConnectionLost, match="cannot open"):
        NmeaReceiver("/nonexistent/ttyGNSS").connect()


# --- the decoder -------------------------------------------------------------------------------


def test_gga_and_rmc_make_a_full_fix_in_either_order() -> None:
    decoder = NmeaDecoder()
    assert decode_all([GGA], decoder) == [] and decoder.undated == 1  # no date yet
    for lines in ([RMC, GGA], [GGA, RMC]):
        (fix,) = decode_all(lines)
        assert fix.utc_s == pytest.approx(764426119.0)  # 1994-03-23 12:35:19 UTC
        assert fix.latitude == pytest.approx(48 + 7.038 / 60)
        assert fix.longitude == pytest.approx(11 + 31.0 / 60)
        assert fix.altitude == pytest.approx(545.4 + 46.9) and fix.geoid_separation == 46.9
        assert (fix.quality, fix.satellites, fix.hdop) == (1, 8, 0.9)
        assert fix.speed == pytest.approx(22.4 * 1852 / 3600)
        assert fix.course == pytest.approx(math.radians(84.4))
        assert fix.recv_ns == 1  # the epoch's last sentence


def test_the_date_rolls_over_at_midnight_and_hemispheres_sign() -> None:
    rmc = sentence("GNRMC,235959.90,A,3345.0000000,S,07030.0000000,W,0.0,0.0,311225,,,A")
    gga = sentence("GNGGA,000000.00,3345.0000000,S,07030.0000000,W,4,20,0.5,500.0,M,30.0,M,,")
    (fix,) = decode_all([rmc.strip(), gga.strip()])
    assert fix.quality == 4
    assert fix.utc_s == pytest.approx(1767225600.0)  # 2026-01-01 00:00:00
    assert (fix.latitude, fix.longitude) == pytest.approx((-33.75, -70.5))
    assert math.isnan(fix.speed)  # RMC of another epoch


def test_no_fix_is_nan_and_other_sentences_are_ignored() -> None:
    lines = [
        RMC,
        sentence("GPGGA,123520,,,,,0,00,99.99,,,,,,").strip(),
        sentence("GPVTG,084.4,T,,M,22.4,N,41.5,K,A").strip(),
        sentence("PUBX,00,123519.00,4807.03800,N").strip(),
        sentence("GPGSV,1,1,01,01,40,083,46").strip(),
    ]
    (no_fix,) = decode_all(lines)  # the RMC's epoch has no GGA: no fix
    assert no_fix.quality == 0 and no_fix.covariance_type == CovarianceType.UNKNOWN
    assert no_fix.utc_s == pytest.approx(764426120.0)  # a time, a date: reported
    assert math.isnan(no_fix.latitude) and math.isnan(no_fix.altitude)
    # a receiver before its first fix sends no time, maybe no date: nothing, no error
    cold = [
        sentence("GPRMC,,V,,,,,,,,,,N").strip(),
        sentence("GPGGA,,,,,,0,00,99.99,,,,,,").strip(),
        sentence("GPRMC,123521,V,,,,,,,,,,N").strip(),  # a time, no date yet
    ]
    assert decode_all(cold) == []
    later = sentence("GPGGA,123522,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,").strip()
    (fix,) = decode_all([RMC, *cold, later])  # the last date is kept
    assert fix.utc_s == pytest.approx(764426122.0) and math.isnan(fix.speed)


@pytest.mark.parametrize(
    ("line", "error", "match"),
    [
        (GGA[:-2] + b"48", NmeaChecksumError, "checksum 48, computed 47"),
        (GGA[:-3], NmeaChecksumError, "no checksum"),
        (GGA[:-1], NmeaChecksumError, "two hex digits"),
        (sentence("GPGGA,123519,4807.038,X,01131.000,E,1,08,0.9,545.4,M,46.9,M,,").strip(),
         NmeaError, "hemisphere"),
        (sentence("GPGGA,123519,4867.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,").strip(),
         NmeaError, "out of range"),
        (sentence("GPGGA,253519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,").strip(),
         NmeaError, "not a time of day"),
        (sentence("GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,inf,M,46.9,M,,").strip(),
         NmeaError, "altitude: not a number"),
        (sentence("GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,320394,,").strip(),
         NmeaError, "not a date"),
        (b"$GPGGA,\xff*00", NmeaError, "not ASCII"),
        (sentence("G!GGA,1").strip(), NmeaError, "address"),
    ],
)  # fmt: skip
def test_bad_sentences_are_typed_errors(line: bytes, error: type, match: str) -> None:
    with pytest.raises(error, match=match):
        NmeaDecoder().decode(Sentence(0, line))



# --- the framer --------------------------------------------------------------------------------


def test_the_framer_cuts_any_split_and_stamps_the_last_byte() -> None:
    stream = RMC + b"\r\n" + b"\x00\x17junk" + GGA + b"\r\n"
    for cut in range(1, len(stream)):
        framer = LineFramer()
        framer.feed(stream[:cut], 100)
        framer.feed(stream[cut:], 200)
        got = []
        while (s := framer.next()) is not None:
            got.append(s)
        assert [s.data for s in got] == [RMC, GGA]
        assert got[0].recv_ns == (100 if cut > len(RMC) + 1 else 200)
        assert got[1].recv_ns == 200


def test_an_overlong_line_is_an_error_and_the_stream_recovers() -> None:
    framer = LineFramer()
    framer.feed(b"$" + b"A" * (MAX_LINE + 10), 1)
    framer.feed(b"B" * 1000 + b"\r\n" + GGA + b"\r\n", 2)
    with pytest.raises(NmeaError, match="longer than"):
        framer.next()
    s = framer.next()
    assert s is not None and s.data == GGA and framer.next() is None


# --- fuzz --------------------------------------------------------------------------------------


def _drain(framer: LineFramer, decoder: NmeaDecoder) -> list[object]:
    out: list[object] = []
    for _ in range(10_000):  # each call consumes a line: bounded
        try:
            s = framer.next()
        except NmeaError as e:
            out.append(e)
            continue
        if s is None:
            return out
        assert isinstance(s, Sentence) and len(s.data) <= MAX_LINE and s.data[:1] == b"$"
        try:
            out.append(decoder.decode(s))
        except NmeaError as e:
            out.append(e)
    raise AssertionError("the framer does not run dry")


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(chunks=st.lists(st.binary(max_size=300), max_size=8))
def test_fuzz_any_bytes_give_fixes_none_or_typed_errors(chunks: list[bytes]) -> None:
    framer, decoder = LineFramer(), NmeaDecoder()
    for i, chunk in enumerate(chunks):
        framer.feed(chunk, i)
        for item in _drain(framer, decoder):
            assert item is None or isinstance(item, Fix | NmeaError)


_FIELD = st.text(alphabet="0123456789.-+NSEWAVMKT eE", max_size=14)


@settings(max_examples=500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    kinds=st.lists(st.sampled_from(["GGA", "RMC", "VTG", "GSA"]), min_size=1, max_size=4),
    fields=st.lists(st.lists(_FIELD, max_size=16), min_size=4, max_size=4),
    noise=st.binary(max_size=8),
)
def test_fuzz_checksummed_sentences_give_fixes_none_or_typed_errors(
    kinds: list[str], fields: list[list[str]], noise: bytes
) -> None:
    """Sentences with good checksums and random fields reach every field parser."""
    framer, decoder = LineFramer(), NmeaDecoder()
    for kind, values in zip(kinds, fields, strict=False):
        framer.feed(noise + sentence("GN" + kind + "," + ",".join(values)), 0)
        for item in _drain(framer, decoder):
            if isinstance(item, Fix):
                assert -90 <= item.latitude <= 90 or math.isnan(item.latitude)
                assert -180 <= item.longitude <= 180 or math.isnan(item.longitude)
                assert 0 <= item.quality <= 9 and math.isfinite(item.utc_s)
            else:
                assert item is None or isinstance(item, NmeaError)


@settings(max_examples=200, deadline=None)
@given(lat=st.floats(-89.9, 89.9), lon=st.floats(-179.9, 179.9), alt=st.floats(-400, 9000))
def test_fuzz_what_the_sim_sends_the_driver_reads(lat: float, lon: float, alt: float) -> None:
    from acq.sim.nmea_device import _ddmm

    la, ns = _ddmm(lat, 2, 7, "NS")
    lo, ew = _ddmm(lon, 3, 7, "EW")
    rmc = sentence(f"GNRMC,101010.50,A,{la},{ns},{lo},{ew},1.0,90.0,010125,,,A").strip()
    gga = sentence(f"GNGGA,101010.50,{la},{ns},{lo},{ew},1,12,0.8,{alt:.3f},M,0.0,M,,").strip()
    (fix,) = decode_all([rmc, gga])
    assert fix.latitude == pytest.approx(lat, abs=2e-9)
    assert fix.longitude == pytest.approx(lon, abs=2e-9)
    assert fix.altitude == pytest.approx(alt, abs=6e-4)
