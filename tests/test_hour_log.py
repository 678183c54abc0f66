"""bench/hour_log.py: a long drive made of time-shifted copies of a short log reads as one
continuous drive (times, ticks inside the SCIP telegrams, counters, the odometry's path,
the metadata), written from the 2 s simulated drive with real SCIP telegrams put in."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from acq.drivers.scip_codec import checksum, encode, encode_lines, parse_scan_reply
from acq.log import LogWriter, info, info_many, read_messages, read_metadata
from acq.log.reader import LogReader
from acq.log.schemas import SCHEMAS, decode
from acq.log.timebase import TimeBase
from acq.motion.odometry import dead_reckon
from acq.sim.drive_log import DriveTruth

END_NS = 2003_000_000_000  # the short drive's last message, host monotonic ns
BENCH = Path(__file__).resolve().parents[1] / "bench" / "hour_log.py"


def _bench() -> ModuleType:
    spec = importlib.util.spec_from_file_location("bench_hour_log", BENCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def _telegram(tick: int) -> bytes:
    """An MD scan telegram of 11 steps stamped ``tick`` ms, as a UTM-30LX sends it."""
    stamp = encode([tick % (1 << 24)], 4)
    data = encode_lines(encode(np.arange(1000, 1011), 3))
    return bytes(
        b"MD0000001001000\n99b\n" + stamp + bytes([checksum(stamp)]) + b"\n" + data + b"\n"
    )


@pytest.fixture(scope="module")
def source(short_drive: tuple[DriveTruth, Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The short drive with a real SCIP telegram in each ``/laser/raw`` message and the
    scanner's ticks unwrapped in its timing, as the recorder writes them."""
    src = short_drive[0].files[0]
    metadata = read_metadata(src)
    # as the recorder: a clock pair at the end; files rolled every 3 s (for --split)
    metadata["clock"] = {
        "realtime_ns": str(1800000000_000000000 + END_NS),
        "monotonic_ns": str(END_NS),
    }
    metadata["config"] = {"yaml": "output:\n  prefix: drive\n  split_minutes: 0.05\n"}
    out = tmp_path_factory.mktemp("hour_source")
    writer = LogWriter(out, metadata=metadata, time_base=TimeBase.of_metadata(metadata))
    topics: set[str] = set()
    for schema, channel, message in read_messages(src):
        assert schema is not None
        if channel.topic not in topics:
            writer.add_channel(channel.topic, SCHEMAS[schema.name])
            topics.add(channel.topic)
        data = bytes(message.data)
        if channel.topic == "/laser/raw":
            raw = decode(schema.name, data)
            raw.data = _telegram(raw.device_ticks[0])
            data = raw.SerializeToString()
        elif channel.topic == "/acq/timing/laser":  # as the recorder: the tick unwrapped
            timing = decode(schema.name, data)
            timing.unwrapped_tick = timing.device_ticks[0]
            data = timing.SerializeToString()
        writer.write(channel.topic, data, message.log_time, message.publish_time)
    writer.close()
    return writer.files[0]


def _read(path: Path) -> dict[str, list[tuple[int, int, object]]]:
    out: dict[str, list[tuple[int, int, object]]] = {}
    reader = LogReader(path, progress=False)
    for schema, channel, message in reader.messages():
        assert schema is not None
        msg = decode(schema.name, message.data)
        out.setdefault(channel.topic, []).append((message.log_time, message.publish_time, msg))
    assert reader.closed
    return out


def _path_length(odometry: list[tuple[int, int, object]]) -> float:
    """The distance from the first to the last pose of the odometry dead reckoned, m."""
    t = np.array([pub for _log, pub, _m in odometry], dtype=np.int64)
    v = np.array([m.speed_mps for _l, _p, m in odometry])  # type: ignore[attr-defined]
    w = np.array([m.yaw_rate_rps for _l, _p, m in odometry])  # type: ignore[attr-defined]
    x, y, _psi = dead_reckon(np.diff(t) * 1e-9, v[:-1], w[:-1])
    return float(math.hypot(x[-1], y[-1]))


def test_half_a_minute_reads_as_one_drive(source: Path, tmp_path: Path) -> None:
    bench = _bench()
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
            longest = max(np.diff(src).max(), 2 * np.median(np.diff(src)))
            assert np.diff(log).max() <= longest + 1e6, topic
    assert all(not c.gaps for c in summary.channels)

    # the scanner's clock runs on: device ticks, unwrapped ticks and the SCIP telegram's
    # own stamp shift together, one scan period apart at every junction as within a copy
    raws = [m[2] for m in after["/laser/raw"]]
    ticks = np.array([r.device_ticks[0] for r in raws])  # type: ignore[attr-defined]
    telegram_ticks = [parse_scan_reply(r.data).timestamp for r in raws]  # type: ignore[attr-defined]
    assert telegram_ticks == ticks.tolist()
    src_steps = np.diff([m[2].device_ticks[0] for m in before["/laser/raw"]])  # type: ignore[attr-defined]
    assert src_steps.min() <= np.diff(ticks).min() and np.diff(ticks).max() <= src_steps.max()
    timing = [m[2] for m in after["/acq/timing/laser"]]
    unwrapped = np.array([t.unwrapped_tick for t in timing])  # type: ignore[attr-defined]
    assert (unwrapped == ticks).all()
    stamps = np.array([t.stamp_ns for t in timing])  # type: ignore[attr-defined]
    assert (stamps == [m[1] for m in after["/acq/timing/laser"]]).all()

    # the Foxglove stamps (UTC) moved with the log: each still its message's publish time
    offset = TimeBase.of_metadata(read_metadata(out)).utc_offset_ns
    for topic in ("/laser/scan", "/camera/image/compressed"):
        for messages in (before[topic], after[topic]):
            utc = [m[2].timestamp.ToNanoseconds() for m in messages]  # type: ignore[attr-defined]
            assert [t - offset for t in utc] == [m[1] for m in messages], topic

    # the clock metadata's pair is at the new end
    clock = read_metadata(out)["clock"]
    assert int(clock["monotonic_ns"]) == last
    assert int(clock["realtime_ns"]) - int(clock["monotonic_ns"]) == 1800000000_000000000

    # counters go on: no scan or frame number comes twice
    for topic in ("/acq/timing/laser", "/acq/timing/camera"):
        seq = np.array([m[2].sequence for m in after[topic]])  # type: ignore[attr-defined]
        assert (np.diff(seq) == 1).all(), topic

    # host clock pairs keep the session's offset; the metadata's pair is at the new end
    pairs = {m[2].realtime_ns - m[2].monotonic_ns for m in after["/acq/clock"]}  # type: ignore[attr-defined]
    assert len(pairs) == 1
    assert len(after["/acq/clock"]) >= 29

    # the odometry's path goes on, not back over the first copy's: dead reckoned, its
    # end as far from its start as its time says
    odo_before, odo_after = before["/vehicle/odometry"], after["/vehicle/odometry"]
    ratio = (odo_after[-1][1] - odo_after[0][1]) / (odo_before[-1][1] - odo_before[0][1])
    assert ratio > 10
    assert _path_length(odo_after) == pytest.approx(ratio * _path_length(odo_before), rel=0.05)


def test_split_as_the_recorder_rolls(source: Path, tmp_path: Path) -> None:
    """--split: a session of files, each rolled after the source configuration's 3 s,
    that reads as one drive."""
    out = tmp_path / "session"
    result = _bench().write_hour_log(source, out, 0.25, split=True)
    files = sorted(out.iterdir())
    assert [str(f) for f in files] == result["files"] and len(files) == 5
    assert all(f.name.startswith("drive_") for f in files)
    session = info_many(files)[-1]  # the whole session, after each file
    assert session.files == tuple(files) and session.problem is None
    assert 15.0 - 0.05 < session.duration_s <= 15.0
    assert all(not c.gaps for c in session.channels)
    assert session.messages == result["messages"]


def test_refuses_what_it_cannot_write(source: Path, tmp_path: Path) -> None:
    bench = _bench()
    existing = tmp_path / "there.mcap"
    existing.write_bytes(b"not yours")
    with pytest.raises(bench.HourLogError, match="never overwritten"):
        bench.write_hour_log(source, existing, 0.5)
    assert existing.read_bytes() == b"not yours"
    with pytest.raises(bench.HourLogError, match="no such folder"):
        bench.write_hour_log(source, tmp_path / "none" / "x.mcap", 0.5)
    with pytest.raises(bench.HourLogError, match="--minutes"):
        bench.write_hour_log(source, tmp_path / "x.mcap", math.nan)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["there.mcap"]
