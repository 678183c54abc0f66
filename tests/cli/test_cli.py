"""The command line's one place for errors: exit statuses, one line, --debug, --version,
a closed or full stdout."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest

from acq import __version__
from acq.cli import main
from acq.log import summary

# `acq info` whose summary is long text, without a log: for the stdout tests
_LONG_INFO = (
    "import sys; from acq.log import summary; "
    "summary.info_many = lambda logs: []; "
    "summary.format_info = lambda info, json: 'a line of the summary\\n' * 200_000; "
    "from acq.cli import main; sys.exit(main(['info', 'x.mcap']))"
)


def _bug(*args: object, **kwargs: object) -> None:
    raise KeyError("channel")


def test_a_bug_exits_1_with_one_line(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(summary, "info_many", _bug)
    assert main(["info", "x.mcap"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("acq info: KeyError: channel") and err.count("\n") == 1, err
    assert "Traceback" not in err and "--debug" in err


@pytest.mark.parametrize("argv", [["--debug", "info", "x.mcap"], ["info", "x.mcap", "--debug"]])
def test_debug_shows_the_traceback(
    argv: list[str], monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(summary, "info_many", _bug)
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert "Traceback (most recent call last)" in err and "in _bug" in err
    assert err.splitlines()[-1] == "acq info: KeyError: channel"


def test_bad_input_exits_2_naming_the_command(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["info", str(tmp_path / "none.mcap")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"acq info: {tmp_path / 'none.mcap'}") and err.count("\n") == 1


@pytest.mark.parametrize(
    "argv", [["--version"], ["info", "--version"], ["calibrate", "fisheye", "--version"],
             ["sim", "scanner", "--version"], ["devices", "--version"]],
)  # fmt: skip
def test_version_on_every_subcommand(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(argv) == 0
    assert capsys.readouterr().out == f"acq {__version__}\n"


def test_a_closed_stdout_ends_quietly() -> None:
    """`acq info LOG | head -1`: the reader goes away mid-output."""
    p = subprocess.Popen(
        [sys.executable, "-c", _LONG_INFO], stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    assert p.stdout is not None and p.stderr is not None
    assert p.stdout.readline() == b"a line of the summary\n"
    p.stdout.close()
    err = p.stderr.read().decode()
    assert p.wait(timeout=60) == 141
    assert err == ""


def test_a_full_stdout_exits_1_with_one_line() -> None:
    with open("/dev/full", "w") as full:
        done = subprocess.run(
            [sys.executable, "-c", _LONG_INFO], stdout=full, stderr=subprocess.PIPE, text=True
        )
    assert done.returncode == 1
    assert done.stderr == "acq info: No space left on device\n"


def test_a_library_warning_is_one_line_of_the_command() -> None:
    script = (
        "import sys, numpy as np; from acq.log import summary; "
        "summary.info_many = lambda logs: [np.float64(1.0) / 0.0][:0]; "
        "summary.format_info = lambda info, json: 'done'; "
        "from acq.cli import main; sys.exit(main(['info', 'x.mcap']))"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert done.returncode == 0 and done.stdout == "done\n"
    assert done.stderr.startswith("acq info: warning: RuntimeWarning: divide by zero")
    assert done.stderr.count("\n") == 1, done.stderr


def test_python_m_acq_cli() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "acq.cli", "info", "--version"], capture_output=True, text=True
    )
    assert done.returncode == 0 and done.stdout == f"acq {__version__}\n"


def test_help_into_a_full_stdout_exits_1_with_one_line() -> None:
    with open("/dev/full", "w") as full:
        done = subprocess.run(
            [sys.executable, "-m", "acq.cli", "colorize", "--help"],
            stdout=full, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
    assert done.returncode == 1
    assert done.stderr == "acq: No space left on device\n"


def test_library_warnings_are_the_commands_lines(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Outside a test's log capture, what a library logs at WARNING reaches stderr as the
    command's line; INFO does not."""
    root = logging.getLogger()
    monkeypatch.setattr(root, "handlers", [])
    monkeypatch.setattr(root, "level", root.level)
    sys.modules["acq.cli.main"]._log_lines("acq colorize")
    logging.getLogger("acq.log").warning("x.mcap: 1 corrupt chunk skipped")
    logging.getLogger("acq.log").info("read x.mcap")
    assert capsys.readouterr().err == "acq colorize: x.mcap: 1 corrupt chunk skipped\n"


@pytest.mark.parametrize(("given", "kept"), [(None, "1"), ("2", "2")])
def test_the_commands_run_one_blas_thread_unless_told(given: str | None, kept: str) -> None:
    """The command line sets OpenBLAS to one thread before numpy loads it (the commands
    run their own threads), and keeps what the user set."""
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if given is not None:
        env["OPENBLAS_NUM_THREADS"] = given
    code = "import os, acq.cli, numpy; print(os.environ['OPENBLAS_NUM_THREADS'])"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True)  # fmt: skip
    assert out.stdout.strip() == kept
