"""Progress bars: library code reports its work in its unit, a bar the command opened
shows it (and ends its line when full); reading logs is shown in bytes for every command
that reads them."""

from __future__ import annotations

from pathlib import Path

import pytest
from mcap.writer import Writer
from tqdm import tqdm

from acq import progress
from acq.cli import main


def test_a_bar_counts_its_unit_and_ends_when_full(capsys: pytest.CaptureFixture[str]) -> None:
    with progress.bar(10, "scan", "colouring", shown=True):
        with progress.bar(99, "scan", "inner", shown=True):  # counted by the outer bar
            progress.advance(4, "scan")
        progress.advance(5, "B")  # no bar counts bytes: nothing
        progress.advance(6, "scan")
    assert progress._bars == {}
    err = capsys.readouterr().err
    assert "colouring: 100%" in err and "10/10" in err and "inner" not in err
    with progress.bar(10, "scan", "hidden", shown=False):
        progress.advance(10, "scan")
    assert capsys.readouterr().err == ""


def _log(path: Path, messages: int) -> None:
    with path.open("wb") as f:
        w = Writer(f, chunk_size=4096)
        w.start()
        schema = w.register_schema("raw", "", b"")
        channel = w.register_channel("/x", "", schema)
        for t in range(messages):
            w.add_message(channel, log_time=t * 10_000_000, data=bytes(500), publish_time=t)
        w.finish()


def test_reading_logs_is_a_bar_in_bytes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    logs = [tmp_path / "a.mcap", tmp_path / "b.mcap"]
    for p in logs:
        _log(p, 400)
    total = sum(p.stat().st_size for p in logs)
    assert main(["info", *map(str, logs), "--progress"]) == 0
    err = capsys.readouterr().err
    shown = [x for x in err.replace("\r", "\n").splitlines() if x]
    size = tqdm.format_sizeof(total, divisor=1000)
    assert shown[-1].startswith("reading: 100%") and f" {size}/{size} " in shown[-1], err
    assert shown[0].startswith("reading:   0%")
    assert main(["info", *map(str, logs)]) == 0  # stderr is no terminal here: no bar
    assert "reading" not in capsys.readouterr().err
