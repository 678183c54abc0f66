"""`acq colorize` and `acq export ros2` stopped by a signal in the middle of writing: the
command ends with one line saying so and the shell's status for the signal, its
temporary removed, the old output as it was; after a SIGKILL, which nothing can catch,
the next run removes the temporary the killed one left, and says so.

The commands are real subprocesses sent real signals. The short drive is written in a
moment, so each is held in the middle of its write: a hook in the subprocess lets the
first part be written into the temporary, leaves a mark for the test, and then waits
(standing in for the rest of a long drive) until the signal comes; only that wait is
added, the writing is acq's own."""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from acq.cli.main import main
from acq.cloud.las import LasStream
from acq.sim.drive_log import DriveTruth

# argv: the mark's path, then acq's arguments
_HOLD = """
import sys, time
from pathlib import Path
mark = Path(sys.argv[1])

def held(real):
    def hold(*args, **kwargs):
        result = real(*args, **kwargs)
        if not mark.exists():
            mark.touch()
            # short sleeps: a signal the kernel hands to another thread of the process
            # does not cut the main thread's sleep short; Python runs the handler at
            # the main thread's next step
            for _ in range(2400):
                time.sleep(0.05)
        return result
    return hold

from acq.cloud.writer import CloudWriter
from rosbags.rosbag2 import Writer
CloudWriter.write = held(CloudWriter.write)
Writer.write = held(Writer.write)
from acq.cli.main import main
sys.exit(main(sys.argv[2:]))
"""


def _held(mark: Path, *argv: str) -> subprocess.Popen[str]:
    """``acq ARGV`` held in the middle of its write (module docstring), in a process
    group of its own (with its workers): returned once there."""
    proc = subprocess.Popen([sys.executable, "-c", _HOLD, str(mark), *argv],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)  # fmt: skip
    deadline = time.monotonic() + 120
    while not mark.exists():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the command never reached its write"
        time.sleep(0.02)
    return proc


def _killed(mark: Path, *argv: str) -> None:
    """``acq ARGV`` killed (SIGKILL) in the middle of its write."""
    proc = _held(mark, *argv)
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=60)


def _acq(caplog: pytest.LogCaptureFixture, *argv: str) -> list[str]:
    """``acq ARGV`` run to its end in this process (the runs that are stopped are the
    subprocesses): its warnings, which the command writes as its own lines on stderr
    (tests/cli/test_cli.py), returned; the exit status checked."""
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        assert main(list(argv)) == 0
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


def _files(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (hidden ones too), by relative path: its bytes."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}  # fmt: skip


@pytest.fixture
def drive_and_folder(
    short_drive: tuple[DriveTruth, Path], tmp_path: Path
) -> tuple[DriveTruth, Path, Path]:
    """The short drive, its calibration, and a folder for the outputs (the marks are
    beside it)."""
    folder = tmp_path / "out"
    folder.mkdir()
    return *short_drive, folder


def _earlier_cloud(path: Path) -> None:
    """A small cloud acq wrote (so that colorize replaces it without --force)."""
    n = 10
    s = LasStream(path)
    flags = np.ones(n, np.uint8)
    s.write(np.zeros((n, 3)), np.zeros((n, 3), np.uint8), np.full(n, 1.7e9), np.ones(n),
            np.arange(n), flags, np.zeros(n, np.uint8), np.zeros(n, np.int32))  # fmt: skip
    s.close()


def _colorize(truth: DriveTruth, calib: Path, out: Path) -> list[str]:
    return ["colorize", *map(str, truth.files), "--calib", str(calib), "-o", str(out),
            "--no-preview", "--chunk", "1"]  # fmt: skip


@pytest.mark.parametrize(
    ("signum", "name"),
    [(signal.SIGTERM, "y.laz"), (signal.SIGHUP, "y.e57"), (signal.SIGINT, "y.ply")],
)
def test_colorize_stopped_by_a_signal_removes_its_temporary_and_keeps_the_old_cloud(
    drive_and_folder: tuple[DriveTruth, Path, Path], tmp_path: Path, signum: int, name: str
) -> None:
    truth, calib, folder = drive_and_folder
    out = folder / name
    old = folder / "y.las"  # the cloud of a former run, beside: untouched
    _earlier_cloud(old)
    if out.suffix == ".laz":
        _earlier_cloud(out)
    before = _files(folder)
    proc = _held(tmp_path / "mark", *_colorize(truth, calib, out))
    assert any(".tmp" in n for n in _files(folder))  # in the middle of the write
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signum, err
    assert err.splitlines()[-1] == (
        f"acq colorize: stopped by {signal.Signals(signum).name}: the file being written "
        "removed, its old output kept"
    )
    assert _files(folder) == before


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_colorize_on_workers_stopped_with_its_workers_says_one_line(
    drive_and_folder: tuple[DriveTruth, Path, Path], tmp_path: Path, signum: int
) -> None:
    """A signal to the whole process group (systemd stopping a unit, a terminal closing):
    the workers and the progress queue's server end at once; the command still ends with
    its one line, no traceback of the queue's reader or of multiprocessing's resource
    tracker (which a SIGHUP would end)."""
    truth, calib, folder = drive_and_folder
    out = folder / "y.laz"
    proc = _held(tmp_path / "mark", *_colorize(truth, calib, out), "--workers", "2")
    time.sleep(0.5)  # the progress queue's reader asks again meanwhile
    os.killpg(proc.pid, signum)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signum, err
    assert err.splitlines() == [
        f"acq colorize: stopped by {signal.Signals(signum).name}: the file being written "
        "removed, its old output kept"
    ]
    assert _files(folder) == {}


def test_colorize_killed_leaves_a_temporary_the_next_run_removes(
    drive_and_folder: tuple[DriveTruth, Path, Path], tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
) -> None:  # fmt: skip
    truth, calib, folder = drive_and_folder
    _earlier_cloud(out := folder / "y.laz")
    before = _files(folder)
    _killed(tmp_path / "mark", *_colorize(truth, calib, out))
    left = [folder / n for n in _files(folder) if n not in before]
    assert len(left) == 1 and left[0].name.startswith(".y.")  # what SIGKILL leaves
    assert _files(folder)["y.laz"] == before["y.laz"]
    warned = _acq(caplog, *_colorize(truth, calib, out))
    assert f"removed a stale temporary {left[0]} left by a run that was killed" in warned
    assert sorted(_files(folder)) == ["y.laz"] and _files(folder)["y.laz"] != before["y.laz"]


def test_export_stopped_or_killed_keeps_the_old_bag_and_leaves_no_work_folder(
    drive_and_folder: tuple[DriveTruth, Path, Path], tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
) -> None:  # fmt: skip
    truth, _, folder = drive_and_folder
    argv = ["export", "ros2", *map(str, truth.files), "-o", str(bag := folder / "bag")]
    _acq(caplog, *argv)
    before = _files(folder)
    proc = _held(tmp_path / "term", *argv)
    assert len(list(folder.iterdir())) == 2  # the bag and the work folder beside it
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert err.splitlines()[-1].startswith("acq export ros2: stopped by SIGTERM: ")
    assert _files(folder) == before
    _killed(tmp_path / "kill", *argv)
    (work,) = (p for p in folder.iterdir() if p != bag)
    warned = _acq(caplog, *argv)
    assert f"removed a stale temporary {work} left by a run that was killed" in warned
    assert [p.name for p in folder.iterdir()] == ["bag"]
