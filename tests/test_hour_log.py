"""bench/hour_log.py: a long drive made of time-shifted copies of a short log reads as one
continuous drive (times, ticks inside the SCIP telegrams, counters, the odometry's path,
the metadata), written from the 2 s simulated drive with real SCIP telegrams put in."""

from __future__ import annotations

import datetime as dt
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from acq.drivers.nmea import NmeaDecoder
from acq.drivers.scip_codec import checksum, encode, encode_lines, parse_scan_reply
from acq.log import LogWriter, info, info_many, read_messages, read_metadata, schemas
from acq.log.acq_proto import TimeBaseMsg
from acq.log.reader import LogReader
from acq.log.schemas import SCHEMAS, DeviceStatus, decode
from acq.log.timebase import TimeBase
from acq.motion.odometry import dead_reckon
from acq.records import CanFrame, Fix, Sentence
from acq.sim.drive_log import DriveTruth
from acq.sim.nmea_device import sentence
from tests import bench_scripts

END_NS = 2003_000_000_000  # the short drive's last message, host monotonic ns


def _telegram(tick: int) -> bytes:
    """An MD scan telegram of 11 steps stamped ``tick`` ms, as a UTM-30LX sends it."""
    stamp = encode([tick % (1 << 24)], 4)
    data = encode_lines(encode(np.arange(1000, 1011), 3))
    return bytes(
        b"MD0000001001000\n99b\n" + stamp + bytes([checksum(stamp)]) + b"\n" + data + b"\n"
    )


@pytest.fixture(scope="module")
def source(short_drive: tuple[DriveTruth, Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The short drive as the recorder writes it: a real SCIP telegram in each
    ``/laser/raw`` message, the scanner's ticks unwrapped in its timing, and its other
    records (:func:`_recorder_extras`)."""
    src = short_drive[0].files[0]
    metadata = read_metadata(src)
    # as the recorder: a clock pair at the end; files rolled every 3 s (for --split)
    metadata["clock"] = {
        "realtime_ns": str(1800000000_000000000 + END_NS),
        "monotonic_ns": str(END_NS),
    }
    metadata["config"] = {"yaml": "output:\n  prefix: drive\n  split_minutes: 0.05\n"}
    metadata["time_base"] = {"utc_trusted": "no", "records": "3", "sources": "", "warnings": ""}
    out = tmp_path_factory.mktemp("hour_source")
    writer = LogWriter(out, metadata=metadata, time_base=TimeBase.of_metadata(metadata))
    messages: list[tuple[str, str, bytes, int, int]] = []
    for schema, channel, message in read_messages(src):
        assert schema is not None
        data = bytes(message.data)
        if channel.topic == "/laser/raw":
            raw = decode(schema.name, data)
            raw.data = _telegram(raw.device_ticks[0])
            data = raw.SerializeToString()
        elif channel.topic == "/acq/timing/laser":  # as the recorder: the tick unwrapped
            timing = decode(schema.name, data)
            timing.unwrapped_tick = timing.device_ticks[0]
            data = timing.SerializeToString()
        messages.append((channel.topic, schema.name, data, message.log_time, message.publish_time))
    messages += _recorder_extras(metadata)
    for topic, schema_name in dict((m[0], m[1]) for m in messages).items():
        writer.add_channel(topic, SCHEMAS[schema_name])
    for topic, _schema, data, log_ns, pub_ns in sorted(messages, key=lambda m: m[3]):
        writer.write(topic, data, log_ns, pub_ns)
    writer.close()
    return writer.files[0]


def _recorder_extras(
    metadata: dict[str, dict[str, str]],
) -> list[tuple[str, str, bytes, int, int]]:
    """What the recorder writes besides the drive (topic, schema, bytes, log and publish
    ns): 1 Hz status and time base readings (with a PPS source), CAN frames and GNSS
    fixes with their timing (the fix time in UTC µs ticks) and sentences (RMC, GGA)."""
    utc = TimeBase.of_metadata(metadata).utc_offset_ns
    out: list[tuple[str, str, bytes, int, int]] = []
    for k in range(3):
        t = 2000_000_000_000 + k * 1_000_000_000 + 5_000_000
        laser = DeviceStatus(name="laser", kind="scanner", received=40 * k, dropped=k)
        data = schemas.status(timestamp_ns=t, uptime_s=k + 0.005, devices=[laser])
        out.append(("/acq/status", "acq.Status", data, t, t))
        base = TimeBaseMsg(realtime_ns=t + utc, monotonic_ns=t)
        base.timestamp.FromNanoseconds(t)
        base.pps.name, base.pps.assert_sequence = "pps0", 100 + k
        base.pps.assert_s = (2000 + k + utc * 1e-9) // 1
        out.append(("/acq/timebase", "acq.TimeBase", base.SerializeToString(), t, t))
    for k in range(100):  # CAN at 50 Hz, GNSS at 10 Hz
        t = 2000_000_000_000 + k * 20_000_000 + 1_000_000
        frame = CanFrame(recv_ns=t + 300_000, stamp_ns=t, wall_ns=t + utc + 200_000,
                         arbitration_id=0x120, data=bytes(8))  # fmt: skip
        out.append(("/vehicle/can", "acq.CanFrame", schemas.can_frame(frame), t + 300_000, t))
        if k % 5 == 0:
            utc_s = (t + utc) * 1e-9
            fix = Fix(recv_ns=t + 45_000_000, utc_s=utc_s, latitude=48.8, longitude=2.3,
                      altitude=35.0, quality=4)  # fmt: skip
            tick = round(utc_s * 1e6)
            timing = schemas.timing(recv_ns=fix.recv_ns, stamp_ns=t, device_ticks=(tick,),
                                    unwrapped_tick=tick, stamp_source="fix")  # fmt: skip
            fixed = schemas.location_fix(fix, t + utc)
            out.append(("/gnss/fix", "foxglove.LocationFix", fixed, fix.recv_ns, t))
            when = dt.datetime.fromtimestamp(utc_s, dt.UTC)
            hms, day = f"{when:%H%M%S}.{when.microsecond // 10_000:02d}", f"{when:%d%m%y}"
            rmc = f"GPRMC,{hms},A,4848.000,N,00218.000,E,10.0,90.0,{day},,,A"
            gga = f"GPGGA,{hms},4848.000,N,00218.000,E,4,14,0.7,35.0,M,47.0,M,,"
            for j, body in enumerate((rmc, gga)):  # received one after the other
                recv = fix.recv_ns - 2000 + 1000 * j
                raw = schemas.raw_telegram(
                    device="gnss", data=sentence(body).rstrip(), recv_ns=recv
                )
                out.append(("/gnss/raw", "acq.RawTelegram", raw, recv, recv))
            out.append(("/acq/timing/gnss", "acq.Timing", timing, fix.recv_ns, t))
    return out


def _read(path: Path) -> dict[str, list[tuple[int, int, Any]]]:
    out: dict[str, list[tuple[int, int, Any]]] = {}
    reader = LogReader(path, progress=False)
    for schema, channel, message in reader.messages():
        assert schema is not None
        msg = decode(schema.name, message.data)
        out.setdefault(channel.topic, []).append((message.log_time, message.publish_time, msg))
    assert reader.closed
    return out


def _path_length(odometry: list[tuple[int, int, Any]]) -> float:
    """The distance from the first to the last pose of the odometry dead reckoned, m."""
    t = np.array([pub for _log, pub, _m in odometry], dtype=np.int64)
    v = np.array([m.speed_mps for _l, _p, m in odometry])
    w = np.array([m.yaw_rate_rps for _l, _p, m in odometry])
    x, y, _psi = dead_reckon(np.diff(t) * 1e-9, v[:-1], w[:-1])
    return float(math.hypot(x[-1], y[-1]))


def test_half_a_minute_reads_as_one_drive(source: Path, tmp_path: Path) -> None:
    bench = bench_scripts.load("hour_log")
    out = tmp_path / "long.mcap"
    result = bench.write_hour_log(source, out, 0.5)
    assert result["files"] == [str(out)] and result["copies"] > 10
    before, after = _read(source), _read(out)
    assert set(after) == set(before)

    # one span of the length asked, every channel in time order and at its pace
    first = min(m[0][0] for m in after.values())
    last = max(m[-1][0] for m in after.values())
    assert 30.0 - 0.05 < (last - first) * 1e-9 <= 30.0  # to the last message before 30 s
    summary = info(out)
    assert summary.closed and summary.problem is None
    for topic, messages in after.items():
        log = np.array([m[0] for m in messages])
        assert (np.diff(log) > 0).all(), topic
        src = np.array([m[0] for m in before[topic]])
        if len(src) > 10:  # a data channel: as many as its rate gives in 30 s, give or
            # take one at each junction; no interval longer than two periods
            rate = (len(src) - 1) / ((src[-1] - src[0]) * 1e-9)
            assert abs(len(messages) - rate * 30.0) <= result["copies"], topic
            d = np.diff(src)  # the pace as acq info takes it: bursts (CAN, NMEA) aside
            pace = np.median(d[d > d.mean() / 10])
            longest = max(d.max(), 2 * pace)
            assert np.diff(log).max() <= longest + 1e6, topic
    assert all(not c.gaps for c in summary.channels)

    # the scanner's clock runs on: device ticks, unwrapped ticks and the SCIP telegram's
    # own stamp shift together, one scan period apart at every junction as within a copy
    raws = [m[2] for m in after["/laser/raw"]]
    ticks = np.array([r.device_ticks[0] for r in raws])
    telegram_ticks = [parse_scan_reply(r.data).timestamp for r in raws]
    assert telegram_ticks == ticks.tolist()
    src_steps = np.diff([m[2].device_ticks[0] for m in before["/laser/raw"]])
    assert src_steps.min() <= np.diff(ticks).min() and np.diff(ticks).max() <= src_steps.max()
    timing = [m[2] for m in after["/acq/timing/laser"]]
    unwrapped = np.array([t.unwrapped_tick for t in timing])
    assert (unwrapped == ticks).all()
    stamps = np.array([t.stamp_ns for t in timing])
    assert (stamps == [m[1] for m in after["/acq/timing/laser"]]).all()

    # the Foxglove stamps (UTC) moved with the log: each still its message's publish time
    offset = TimeBase.of_metadata(read_metadata(out)).utc_offset_ns
    for topic in ("/laser/scan", "/camera/image/compressed"):
        for messages in (before[topic], after[topic]):
            utc = [m[2].timestamp.ToNanoseconds() for m in messages]
            assert [t - offset for t in utc] == [m[1] for m in messages], topic

    # the clock metadata's pair is at the new end
    clock = read_metadata(out)["clock"]
    assert int(clock["monotonic_ns"]) == last
    assert int(clock["realtime_ns"]) - int(clock["monotonic_ns"]) == 1800000000_000000000

    # counters go on: no scan or frame number comes twice
    for topic in ("/acq/timing/laser", "/acq/timing/camera"):
        seq = np.array([m[2].sequence for m in after[topic]])
        assert (np.diff(seq) == 1).all(), topic

    # host clock pairs keep the session's offset; the metadata's pair is at the new end
    pairs = {m[2].realtime_ns - m[2].monotonic_ns for m in after["/acq/clock"]}
    assert len(pairs) == 1
    assert len(after["/acq/clock"]) >= 29

    # the odometry's path goes on, not back over the first copy's: dead reckoned, its
    # end as far from its start as its time says
    odo_before, odo_after = before["/vehicle/odometry"], after["/vehicle/odometry"]
    ratio = (odo_after[-1][1] - odo_after[0][1]) / (odo_before[-1][1] - odo_before[0][1])
    assert ratio > 10
    assert _path_length(odo_after) == pytest.approx(ratio * _path_length(odo_before), rel=0.05)


def test_the_recorders_other_records_run_on(source: Path, tmp_path: Path) -> None:
    """Status, time base readings, CAN frames and GNSS fixes: their host and UTC times
    and their counters go on across the copies."""
    out = tmp_path / "long.mcap"
    bench_scripts.load("hour_log").write_hour_log(source, out, 0.25)
    after = _read(out)
    offset = TimeBase.of_metadata(read_metadata(out)).utc_offset_ns

    status = [m[2] for m in after["/acq/status"]]
    assert len(status) >= 14
    assert np.all(np.diff([s.uptime_s for s in status]) > 0.9)
    received = [s.devices[0].received for s in status]
    dropped = [s.devices[0].dropped for s in status]
    assert np.all(np.diff(received) == 40) and np.all(np.diff(dropped) == 1)

    bases = [m[2] for m in after["/acq/timebase"]]
    assert {b.realtime_ns - b.monotonic_ns for b in bases} == {offset}
    assert np.all(np.diff([b.pps.assert_sequence for b in bases]) == 1)
    pulses = np.diff([b.pps.assert_s for b in bases])
    assert np.all((pulses > 0) & (pulses < 2))
    assert read_metadata(out)["time_base"]["records"] == str(len(bases))

    frames = after["/vehicle/can"]
    assert {m[2].wall_ns - m[2].recv_ns for m in frames} == {offset - 100_000}
    assert {m[2].timestamp.ToNanoseconds() for m in frames} == {m[1] for m in frames}

    fixes, timing = after["/gnss/fix"], after["/acq/timing/gnss"]
    assert len(fixes) == len(timing) >= 140
    for (_log, pub, fix), (_l, _p, tim) in zip(fixes, timing, strict=True):
        utc_s = float(dict((kv.key, kv.value) for kv in fix.metadata)["utc_s"])
        assert utc_s == pytest.approx((pub + offset) * 1e-9, abs=1e-3)
        assert tim.device_ticks[0] == tim.unwrapped_tick == round((pub + offset) / 1e3)
    decoder = NmeaDecoder()  # the receiver's own sentences tell the same times
    decoded = [
        decoder.decode(Sentence(recv_ns=pub, data=raw.data)) for _l, pub, raw in after["/gnss/raw"]
    ]
    said = [f.utc_s for f in [*decoded, *decoder.flush()] if f is not None]
    expected = [(pub + offset) * 1e-9 for _l, pub, _f in fixes]
    assert said == pytest.approx(expected, abs=0.011)  # to the 10 ms of their fields


def test_split_as_the_recorder_rolls(source: Path, tmp_path: Path) -> None:
    """--split: a session of files, each rolled after the source configuration's 3 s,
    that reads as one drive."""
    out = tmp_path / "session"
    result = bench_scripts.load("hour_log").write_hour_log(source, out, 0.25, split=True)
    files = sorted(out.iterdir())
    assert [str(f) for f in files] == result["files"] and len(files) == 5
    assert all(f.name.startswith("drive_") for f in files)
    session = info_many(files)[-1]  # the whole session, after each file
    assert session.files == tuple(files) and session.problem is None
    assert 15.0 - 0.05 < session.duration_s <= 15.0
    assert all(not c.gaps for c in session.channels)
    assert session.messages == result["messages"]


def test_refuses_what_it_cannot_write(source: Path, tmp_path: Path) -> None:
    bench = bench_scripts.load("hour_log")
    existing = tmp_path / "there.mcap"
    existing.write_bytes(b"not yours")
    with pytest.raises(bench.HourLogError, match="never overwritten"):
        bench.write_hour_log(source, existing, 0.5)
    assert existing.read_bytes() == b"not yours"
    with pytest.raises(bench.HourLogError, match="no such folder"):
        bench.write_hour_log(source, tmp_path / "none" / "x.mcap", 0.5)
    with pytest.raises(bench.HourLogError, match="--minutes"):
        bench.write_hour_log(source, tmp_path / "x.mcap", math.nan)
    cut = tmp_path / "cut.mcap"  # a log whose writer stopped: not repeated
    cut.write_bytes(source.read_bytes()[: source.stat().st_size // 2])
    with pytest.raises(bench.HourLogError, match=r"cut\.mcap: not a closed log"):
        bench.write_hour_log(cut, tmp_path / "x.mcap", 0.5)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cut.mcap", "there.mcap"]
