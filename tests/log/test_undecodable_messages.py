"""Messages whose payloads or schema the file garbled, in a real MCAP log of a simulated
drive (sim/drive_log.py) copied with mcap's writer: counted per channel, one WARNING per
channel with the count (never one per message), shown by `acq info`, and named when a
command finds nothing else to read."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest

from acq.cli import main as acq_main
from acq.log.reader import LogReader
from acq.sim.drive_log import DriveTruth
from acq.sim.replay import ReplayError, load_session
from tests.log_rewrite import mcap_copy

GARBAGE = b"\xff\xff\xff\xff"  # a protobuf tag with a varint that never ends


def _warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


def test_garbled_scan_payloads_are_one_warning_counted_and_named(
    short_drive: tuple[DriveTruth, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
) -> None:
    truth, calib = short_drive
    log = tmp_path / "garbled.mcap"
    counts = mcap_copy(truth.files[0], log, lambda t, d: GARBAGE if t.endswith("/scan") else d)
    (scan_topic,) = [t for t in counts if t.endswith("/scan")]
    n = counts[scan_topic]
    assert n > 20

    reader = LogReader(log)
    with caplog.at_level(logging.WARNING):
        for s, c, m in reader.messages():
            reader.decode(s, c, m)
    assert reader.undecodable == {scan_topic: n}
    (line,) = _warnings(caplog)
    assert line.startswith(
        f"{log}: {scan_topic} (foxglove.LaserScan) cannot be decoded: garbled payloads"
        " (DecodeError: "
    ) and line.endswith(f"; {n} messages skipped"), line

    assert acq_main(["info", str(log)]) == 0
    out = capsys.readouterr().out
    assert "messages that cannot be decoded" in out and f"{scan_topic} {n} of {n}" in out, out
    assert acq_main(["info", "--json", str(log)]) == 0
    (summary,) = json.loads(capsys.readouterr().out)
    by_topic = {c["topic"]: c for c in summary["channels"]}
    assert by_topic[scan_topic]["undecodable"] == n
    assert all(c["undecodable"] == 0 for t, c in by_topic.items() if t != scan_topic)

    out_ply = tmp_path / "c.ply"
    argv = ["colorize", str(log), "--calib", str(calib), "-o", str(out_ply), "--no-preview"]
    assert acq_main(argv) == 2
    err = capsys.readouterr().err
    assert f"{n} {scan_topic} messages cannot be decoded" in err, err
    assert "no /<name>/scan messages" not in err


def test_garbled_camera_records_are_one_warning_in_replay(
    short_drive: tuple[DriveTruth, Path], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    truth, _ = short_drive
    log = tmp_path / "garbled.mcap"
    counts = mcap_copy(
        truth.files[0], log, lambda t, d: GARBAGE if t.endswith("/image/compressed") else d
    )
    (topic,) = [t for t in counts if t.endswith("/image/compressed")]
    with caplog.at_level(logging.WARNING):
        # a simulated drive has no device metadata: refused, after its records were read
        with pytest.raises(ReplayError, match=r"no device\.laser metadata"):
            load_session([log])
    lines = [w for w in _warnings(caplog) if topic in w]
    (line,) = lines
    assert line.startswith(
        f"{log}: {topic} (foxglove.CompressedImage) cannot be decoded: garbled payloads"
    ) and line.endswith(f"; {counts[topic]} messages skipped"), line


def test_a_garbled_schema_in_export_ros2_is_one_warning(
    short_drive: tuple[DriveTruth, Path],
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
    capsys: pytest.CaptureFixture[str],
) -> None:
    truth, _ = short_drive
    log = tmp_path / "garbled.mcap"
    counts = mcap_copy(
        truth.files[0], log,
        schema_data=lambda s: b"\xff\x00garbage" if s.name == "foxglove.LaserScan" else s.data,
    )  # fmt: skip
    (topic,) = [t for t in counts if t.endswith("/scan")]
    with caplog.at_level(logging.WARNING):
        acq_main(["export", "ros2", str(log), "-o", str(tmp_path / "bag")])
    out = capsys.readouterr()
    lines = [w for w in _warnings(caplog) if topic in w]
    assert len(lines) == 1 and lines[0].endswith(f"; {counts[topic]} messages skipped"), lines
    assert lines[0].startswith(f"{log}: {topic} (foxglove.LaserScan) cannot be decoded: its schema")
    assert (out.out + out.err).count(topic) <= 1, out
