"""A log that was not closed is named once, with the span read, by every command that reads it."""

from __future__ import annotations

import logging
import re
from pathlib import Path

import pytest

from acq.cli import main as acq_main
from acq.log import writer_lock
from acq.sim.drive_log import DriveTruth
from tests.log_rewrite import rewrite

NOTE = re.compile(
    r"(?P<file>\S+): was not closed \(its writer stopped\): read up to (?P<s>[\d.]+) s of it"
    r" \(log time [\d.]+\.\.[\d.]+ s\)"
)


@pytest.fixture(scope="module")
def cut_log(short_drive: tuple[DriveTruth, Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The first 70 % of the short drive in 256 KiB chunks: a log whose writer stopped
    mid-file (each test copies it, so each is the first to read its file)."""
    truth, _ = short_drive
    [src], _ = rewrite(truth.files, tmp_path_factory.mktemp("cut"), chunk_size=256 << 10)
    data = src.read_bytes()
    cut = src.with_name("cut.mcap")
    cut.write_bytes(data[: len(data) * 7 // 10])
    return cut


def _notes(caplog: pytest.LogCaptureFixture) -> list[re.Match[str]]:
    lines = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    return [m for line in lines if (m := NOTE.fullmatch(line))]


@pytest.mark.parametrize("command", ["colorize", "export ros2"])
def test_a_cut_log_is_named_once_with_its_span(
    command: str,
    cut_log: Path,
    short_drive: tuple[DriveTruth, Path],
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
) -> None:
    _, calib = short_drive
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(cut_log.read_bytes())
    if command == "colorize":
        argv = ["colorize", str(cut), "--calib", str(calib), "-o", str(tmp_path / "c.ply")]
        argv.append("--no-preview")
    else:
        argv = ["export", "ros2", str(cut), "-o", str(tmp_path / "bag")]
    with caplog.at_level(logging.WARNING):
        assert acq_main(argv) == 0
    [note] = _notes(caplog)
    assert note["file"] == str(cut)
    assert 0.3 < float(note["s"]) < 1.9  # 70 % of a 2 s drive, give or take a chunk


def test_a_closed_log_says_nothing(
    short_drive: tuple[DriveTruth, Path], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    truth, _ = short_drive
    [src] = truth.files
    with caplog.at_level(logging.WARNING):
        assert acq_main(["export", "ros2", str(src), "-o", str(tmp_path / "bag")]) == 0
    assert _notes(caplog) == []


def test_a_log_being_written_says_so(
    cut_log: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    log = tmp_path / "live.mcap"
    log.write_bytes(cut_log.read_bytes())
    with log.open("rb") as held:  # the recorder's lock, held here as a live recorder would
        writer_lock.hold(held.fileno())
        with caplog.at_level(logging.WARNING):
            assert acq_main(["export", "ros2", str(log), "-o", str(tmp_path / "bag")]) == 0
    lines = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    [line] = [x for x in lines if x.startswith(f"{log}: ")]
    assert line.startswith(f"{log}: is being written (its recorder is running): read up to ")
