"""A log given as something that cannot be read by seeking (a named pipe): named with
what it is, exit 2, at once; never opened, so a FIFO without a writer does not block and
one with a writer loses none of its bytes to a glance."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize(
    "command", [["info"], ["export", "ros2", "-o", "bag"]], ids=["info", "export-ros2"]
)
def test_a_fifo_given_as_a_log_is_named_exit_2(tmp_path: Path, command: list[str]) -> None:
    fifo = tmp_path / "drive.mcap"
    os.mkfifo(fifo)
    done = subprocess.run(
        [sys.executable, "-m", "acq.cli", *command[:2], str(fifo), *command[2:]],
        cwd=tmp_path, capture_output=True, text=True, timeout=30,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    (line,) = done.stderr.strip().splitlines()
    assert f"{fifo}: a named pipe (FIFO): a log is read by seeking in it" in line, line
    assert "a bug?" not in line
    assert not (tmp_path / "bag").exists()
