"""NMEA 0183: the simulated receiver on a real pseudo-terminal -> the driver -> fixes
matching the truth; checksum errors and line noise typed and counted; reconnection
after the port goes away; the framer and the decoder fuzzed. Nothing is mocked."""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from acq.drivers.errors import ConnectionLost, ReadTimeout
from acq.drivers.nmea import (
    MAX_LINE,
    UERE_M,
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


# --- epochs: any order, any grouping ------------------------------------------------------------


def _epoch(
    k: int, order: tuple[str, ...], rmc_motion: bool = True, gsa_runs: int = 1
) -> list[bytes]:
    """Epoch k of a 1 Hz receiver sending ``order``: values that differ per epoch."""
    hms = f"1200{k:02d}.00"
    knots, course = 10.0 + k, 20.0 + k
    motion = f"{knots:.1f},{course:.1f}" if rmc_motion else ","
    bodies = {
        "GGA": f"GNGGA,{hms},4807.{k:03d},N,01131.000,E,1,12,{0.5 + k / 100:.2f},545.4,M,46.9,M,,",
        "RMC": f"GNRMC,{hms},A,4807.{k:03d},N,01131.000,E,{motion},230394,,,A",
        "VTG": f"GNVTG,{course:.1f},T,,M,{knots:.1f},N,,K,A",
        "GST": f"GNGST,{hms},0.1,,,,{0.01 * (k + 1):.3f},{0.02 * (k + 1):.3f},{0.03 * (k + 1):.3f}",
        "GSA": f"GNGSA,A,3,01,02,,,,,,,,,,,1.5,{0.5 + k / 100:.2f},{0.8 + k / 100:.2f}",
    }
    out = []
    for kind in order:
        out += [sentence(bodies[kind]).strip()] * (gsa_runs if kind == "GSA" else 1)
    return out


def _check_epoch_fix(fix: Fix, k: int, kinds: set[str], rmc_motion: bool = True) -> None:
    assert fix.utc_s == pytest.approx(764424000.0 + k)
    assert fix.latitude == pytest.approx(48 + (7 + k / 1000) / 60)
    if (rmc_motion and "RMC" in kinds) or "VTG" in kinds:
        assert fix.speed == pytest.approx((10.0 + k) * 1852 / 3600)
        assert fix.course == pytest.approx(math.radians(20.0 + k))
    else:
        assert math.isnan(fix.speed) and math.isnan(fix.course)
    if "GST" in kinds:
        assert fix.covariance_type == CovarianceType.DIAGONAL_KNOWN
        sigmas = (fix.sigma_north, fix.sigma_east, fix.sigma_up)
        assert sigmas == pytest.approx((0.01 * (k + 1), 0.02 * (k + 1), 0.03 * (k + 1)))
    else:
        hdop = 0.5 + k / 100
        assert fix.covariance_type == CovarianceType.APPROXIMATED
        assert fix.sigma_east == fix.sigma_north == pytest.approx(hdop * UERE_M / math.sqrt(2))
        up = (0.8 + k / 100) if "GSA" in kinds else 2 * hdop
        assert fix.sigma_up == pytest.approx(up * UERE_M)
        assert math.isnan(fix.vdop) != ("GSA" in kinds)


ORDERS = [
    ("RMC", "VTG", "GGA"),  # u-blox's default
    ("GGA", "RMC"),  # GGA first: a fix is the GGA's epoch, not the RMC before it
    ("GGA", "GSA", "GST", "RMC", "VTG"),
    ("GSA", "GSA", "VTG", "GGA", "GST", "RMC"),  # untimed sentences lead the epoch
    ("GST", "GGA", "RMC"),
    ("RMC", "GGA", "GSA"),
    ("GGA", "VTG", "RMC"),
]


@pytest.mark.parametrize("order", ORDERS, ids="-".join)
@pytest.mark.parametrize("rmc_motion", [True, False], ids=["rmc-motion", "vtg-motion"])
def test_each_epoch_gives_one_whole_fix_at_its_last_sentence(
    order: tuple[str, ...], rmc_motion: bool
) -> None:
    decoder = NmeaDecoder()
    fixes: list[tuple[int, int, Fix]] = []  # epoch, sentence index in it, fix
    for k in range(6):
        for i, line in enumerate(_epoch(k, order, rmc_motion)):
            fix = decoder.decode(Sentence(k * 100 + i, line))
            if fix is not None:
                fixes.append((k, i, fix))
    tail = decoder.flush()
    assert len(fixes) + len(tail) == 6 and decoder.late == 0
    got = [f for _, _, f in fixes] + tail
    for k, fix in enumerate(got):
        _check_epoch_fix(fix, k, set(order), rmc_motion)
        assert fix.recv_ns == k * 100 + len(order) - 1  # the receipt of its last sentence
    # the first fix waits for the next epoch's first timed sentence (what an epoch holds is
    # not known yet); then each comes with its epoch's last sentence: no latency
    first_timed = min(i for i, kind in enumerate(order) if kind in ("GGA", "RMC", "GST"))
    assert fixes[0][:2] == (1, first_timed)
    assert [(k, i) for k, i, _ in fixes[1:]] == [(k, len(order) - 1) for k in range(1, 6)]
    assert tail == []


def test_a_gsa_per_constellation_stays_in_its_epoch() -> None:
    decoder = NmeaDecoder()
    lines = [line for k in range(4) for line in _epoch(k, ("RMC", "GGA", "GSA"), gsa_runs=3)]
    fixes = decode_all(lines, decoder)
    assert len(fixes) == 4
    for k, fix in enumerate(fixes):
        _check_epoch_fix(fix, k, {"RMC", "GGA", "GSA"})


def test_a_receiver_that_starts_sending_gst_late_loses_no_fix_and_duplicates_none() -> None:
    decoder = NmeaDecoder()
    lines = _epoch(0, ("RMC", "GGA")) + _epoch(1, ("RMC", "GGA")) + _epoch(2, ("RMC", "GGA", "GST"))
    lines += _epoch(3, ("RMC", "GGA", "GST")) + _epoch(4, ("RMC", "GGA", "GST"))
    fixes = decode_all(lines, decoder)
    assert [round(f.utc_s) - 764424000 for f in fixes] == [0, 1, 2, 3, 4]
    # epoch 2 went out at its GGA; its GST came late (dropped, then waited for)
    assert decoder.late == 1
    assert [f.covariance_type for f in fixes] == [1, 1, 1, 2, 2]


def test_an_untimed_sentence_after_its_epoch_went_out_is_waited_for_from_then_on() -> None:
    decoder = NmeaDecoder()
    lines = [line for k in range(2) for line in _epoch(k, ("RMC", "GGA"), rmc_motion=False)]
    lines += [line for k in range(2, 5) for line in _epoch(k, ("RMC", "GGA", "VTG", "GSA"), False)]
    fixes = decode_all(lines, decoder)
    assert [round(f.utc_s) - 764424000 for f in fixes] == [0, 1, 2, 3, 4]
    # epoch 2 went out at its GGA, before its VTG and GSA: those were late, not the
    # next epoch's; from epoch 3 on each fix has its own
    assert decoder.late == 2 and math.isnan(fixes[2].course)
    for k in (3, 4):
        _check_epoch_fix(fixes[k], k, {"RMC", "GGA", "VTG", "GSA"}, rmc_motion=False)


def test_without_gst_or_dops_the_covariance_is_unknown() -> None:
    gga = sentence("GNGGA,120000.00,4807.000,N,01131.000,E,1,12,,545.4,M,46.9,M,,").strip()
    rmc = sentence("GNRMC,120000.00,A,4807.000,N,01131.000,E,1.0,2.0,230394,,,A").strip()
    (fix,) = decode_all([gga, rmc])
    assert fix.covariance_type == CovarianceType.UNKNOWN and math.isnan(fix.sigma_east)


# --- every order and choice of sentences from the simulated receiver, over its pty ---------------


RECEIVERS = [
    (("GGA", "RMC"), True),  # GGA first
    (("RMC", "GGA", "GSA"), True),  # RMC first, no GST: DOPs x UERE
    (("GGA", "GST", "RMC", "VTG", "GSA"), True),  # with GST
    (("GGA", "VTG", "RMC"), False),  # course and speed in VTG only
]


def test_the_simulated_receiver_in_each_order() -> None:
    """One receiver on its pty, reconfigured in turn to each order and choice of
    sentences (a pty costs 0.5 s to close: one for all)."""
    device = NmeaDevice(CURVY, rate_hz=20.0, jitter_s=0.0, latency_s=0.01)
    with NmeaPtyServer(device).start() as server, NmeaReceiver(server.url) as rx:
        rx.connect()
        for sentences, rmc_motion in RECEIVERS:
            device.sentences, device.rmc_motion = sentences, rmc_motion
            switched = time.monotonic() + device.utc_offset_s
            fixes: list[Fix] = []
            while len(fixes) < 4:
                fix = rx.read_fix()
                # from the second epoch in the new order (the first may be half the old one's)
                if fix.utc_s > switched + 0.075:
                    fixes.append(fix)
            check_against_truth(device, fixes, sentences)


def check_against_truth(device: NmeaDevice, fixes: list[Fix], sentences: tuple[str, ...]) -> None:
    truth = {round(t.utc_s, 2): t for t in device.truth}
    np.testing.assert_allclose(np.diff([f.utc_s for f in fixes]), 0.05, atol=1e-6)
    for fix in fixes:
        t = truth[round(fix.utc_s, 2)]
        assert fix.latitude == pytest.approx(t.latitude, abs=2e-9)
        assert fix.speed == pytest.approx(t.speed, abs=3e-4)
        assert fix.course == pytest.approx(t.course, abs=1e-4)
        if "GST" in sentences:
            assert fix.covariance_type == CovarianceType.DIAGONAL_KNOWN
            assert (fix.sigma_north, fix.sigma_east, fix.sigma_up) == device.gst_sigma
        else:
            assert fix.covariance_type == CovarianceType.APPROXIMATED
            assert fix.sigma_east == pytest.approx(device.hdop * UERE_M / math.sqrt(2))
            vdop = device.vdop if "GSA" in sentences else 2 * device.hdop
            assert fix.sigma_up == pytest.approx(vdop * UERE_M)


def test_the_last_epoch_comes_out_when_the_receiver_falls_silent() -> None:
    """A receiver that stops after one epoch (never learned whole): its fix is given out
    at the read timeout, once, then the timeout is raised."""
    master, slave = os.openpty()
    try:
        with NmeaReceiver(os.ttyname(slave), timeout=0.1) as rx:
            rx.connect()
            os.write(master, b"\r\n".join([GGA, RMC, b""]))
            fix = rx.read_fix()
            assert fix.utc_s == pytest.approx(764426119.0) and math.isfinite(fix.course)
            with pytest.raises(ReadTimeout):
                rx.read_fix()
    finally:
        os.close(master)
        os.close(slave)


# --- fuzz: sequences of sentences ---------------------------------------------------------------


_POOL = [line for k in range(3) for line in _epoch(k, ("GGA", "RMC", "VTG", "GST", "GSA"))] + [
    sentence(
        "GNGGA,120001.00,4807.000,N,01131.000,E,1,12,0.5,545.4,M,46.9,M,,", corrupt=True
    ).strip(),
    sentence("GNGST,120001.00,0.1,,,,-1,0.2,0.3").strip(),
    sentence("GNGSA,A,3,,,,,,,,,,,,,x,y,z").strip(),
    sentence("GNVTG,abc,T,,M,1,N,,K,A").strip(),
    sentence("GNGGA,120002.00,,,,,0,00,99.99,,,,,,").strip(),
    sentence("GNRMC,235959.99,A,4807.000,N,01131.000,E,1.0,2.0,010100,,,A").strip(),
    sentence("GNGST,,,,,,,,").strip(),
    sentence("GNGSA,A,1,,,,,,,,,,,,,,,").strip(),
    b"$GNGGA,\\x00*00",
]


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.sampled_from(_POOL), max_size=40))
def test_fuzz_any_sequence_of_sentences_gives_fixes_or_typed_errors(lines: list[bytes]) -> None:
    decoder = NmeaDecoder()
    fixes: list[Fix] = []
    for i, line in enumerate(lines):
        try:
            fix = decoder.decode(Sentence(i, line))
        except NmeaError:
            continue
        if fix is not None:
            fixes.append(fix)
    fixes += decoder.flush()
    assert decoder.flush() == []
    for fix in fixes:
        assert isinstance(fix, Fix) and math.isfinite(fix.utc_s)
        assert fix.covariance_type in tuple(CovarianceType)
        sigmas = (fix.sigma_east, fix.sigma_north, fix.sigma_up)
        assert all(s >= 0 for s in sigmas) or fix.covariance_type == CovarianceType.UNKNOWN


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    order=st.permutations(["GGA", "RMC", "VTG", "GST", "GSA"]),
    keep=st.sets(st.sampled_from(["VTG", "GST", "GSA"])),
    epochs=st.integers(1, 5),
)
def test_fuzz_any_fixed_order_gives_each_epoch_once_and_whole(
    order: list[str], keep: set[str], epochs: int
) -> None:
    sent = tuple(k for k in order if k in keep | {"GGA", "RMC"})
    lines = [line for k in range(epochs) for line in _epoch(k, sent)]
    fixes = decode_all(lines)
    assert len(fixes) == epochs
    for k, fix in enumerate(fixes):
        _check_epoch_fix(fix, k, set(sent))


def test_sentences_that_arrived_are_read_when_the_read_comes_late(
    receiver: tuple[NmeaDevice, NmeaPtyServer],
) -> None:
    """A read that runs after its deadline (a host busy elsewhere held the thread: here,
    timeout 0) still takes the sentences already in the port."""
    _, server = receiver
    with NmeaReceiver(server.url, timeout=2.0) as rx:
        rx.connect()
        rx.read_sentence()
        time.sleep(0.5)  # a fix a 0.1 s, several sentences each, pile up in the port
        rx.timeout = 0.0
        late: list[Sentence] = []
        with pytest.raises(ReadTimeout):
            for _ in range(200):
                late.append(rx.read_sentence())
    assert len(late) >= 5
