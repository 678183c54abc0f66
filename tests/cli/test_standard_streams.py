"""`acq` started with its standard streams closed (`acq ... >&-`): /dev/null takes their
place, so a command ends as it would with them open, without a traceback, and nothing
meant for stderr lands on stdout."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def acq_closing(closing: str, *args: str, stderr: Path) -> subprocess.CompletedProcess[bytes]:
    """`acq ARGS` with the standard streams ``closing`` closes (``>&-``...)."""
    with stderr.open("wb") as err:
        return subprocess.run(
            ["sh", "-c", f'exec "$@" {closing}', "sh", sys.executable, "-m", "acq.cli", *args],
            cwd=ROOT, stdout=subprocess.PIPE, stderr=err, timeout=60,
        )  # fmt: skip


@pytest.mark.parametrize("closing", [">&-", "<&- >&-", "2>&- >&-"])
def test_a_command_with_a_closed_stdout_exits_0(closing: str, tmp_path: Path) -> None:
    err = tmp_path / "err.txt"  # stderr, where the case leaves it open
    done = acq_closing(closing, "--version", stderr=err)
    assert done.returncode == 0, err.read_text()
    assert err.read_text() == ""


def test_a_command_with_a_closed_stderr_keeps_its_error_off_stdout(tmp_path: Path) -> None:
    done = acq_closing("<&- 2>&-", "info", str(tmp_path / "none.mcap"), stderr=tmp_path / "e")
    assert done.returncode == 2  # the missing file, a bad input: not a crash (1)
    assert done.stdout == b""
