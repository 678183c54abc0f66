"""A COPC output on a full disk: copclib aborts the whole process on a failed write
(SIGABRT, exit 134, its temporary left behind), so the writer checks the room before
each node it hands copclib, and its own scratch writes name the output when they fail.
The answer is one line naming the output and the disk, exit 3 (the disk reserve's, as
for every output: acq.disk_space), nothing left behind."""

from __future__ import annotations

import errno
import os
import resource
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from acq.cli import main as acq_main
from acq.cloud import copc
from acq.cloud.copc import CopcStream
from acq.sim.drive_log import DriveTruth
from acq.sim.long_cloud import parts


def _limit_file_size() -> None:
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails (EFBIG)
    resource.setrlimit(resource.RLIMIT_FSIZE, (200_000, 200_000))


def test_colorize_to_copc_past_the_file_size_limit_exits_3_leaving_nothing(
    tmp_path: Path, short_drive: tuple[DriveTruth, Path]
) -> None:
    """A real file size limit (RLIMIT_FSIZE, no root needed) on a real `acq colorize`:
    its writes fail with EFBIG as on a full disk."""
    truth, calib = short_drive
    out = tmp_path / "c.copc.laz"
    done = subprocess.run(
        [sys.executable, "-m", "acq.cli", "colorize", *map(str, truth.files), "--calib",
         str(calib), "-o", str(out), "--no-preview"],
        capture_output=True, text=True, preexec_fn=_limit_file_size, timeout=120,
    )  # fmt: skip
    assert done.returncode == 3, done.stderr
    assert done.stderr.startswith(f"acq colorize: {out}: too large for the disk of {tmp_path} ")
    assert len(done.stderr.splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


def _little_room(monkeypatch: pytest.MonkeyPatch, free_bytes: int) -> None:
    """The disk reports ``free_bytes`` free: a full disk cannot be made here without
    root, so os.statvfs (the lowest layer) is replaced; the files written are real."""
    real = os.statvfs

    def statvfs(path: str | os.PathLike[str]) -> os.statvfs_result:
        s = real(path)
        return os.statvfs_result((*s[:4], free_bytes // s.f_frsize, *s[5:]))

    monkeypatch.setattr(copc.os, "statvfs", statvfs)


def test_a_copc_writer_stops_before_a_node_the_disk_has_no_room_for(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _little_room(monkeypatch, 500_000)
    out = tmp_path / "c.copc.laz"
    stream = CopcStream(out)
    for p in parts(2.0):
        stream.write(*p)
    with pytest.raises(OSError) as e:
        stream.close()
    assert e.value.errno == errno.ENOSPC and e.value.filename == str(out)
    assert f"free on the disk of {tmp_path}" in str(e.value.strerror)
    assert list(tmp_path.iterdir()) == []


def test_colorize_to_copc_on_a_full_disk_says_so_in_one_line(
    tmp_path: Path, short_drive: tuple[DriveTruth, Path], monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    truth, calib = short_drive
    _little_room(monkeypatch, 500_000)
    out = tmp_path / "c.copc.laz"
    argv = ["colorize", *map(str, truth.files), "--calib", str(calib), "-o", str(out)]
    assert acq_main([*argv, "--no-preview"]) == 3
    last = capsys.readouterr().err.splitlines()[-1]
    assert last == f"acq colorize: {out}: no space left on the disk of {tmp_path} (0.5 MB free)"
    assert list(tmp_path.iterdir()) == []


_DROP_CHILD = """
import sys
from pathlib import Path
import numpy as np
from acq.cloud.octree import Scratch, drop_all

made = set()
scratch = Scratch(Path(sys.argv[1]), np.dtype("u1"), made)
scratch.append(np.zeros(199_000, np.uint8))
scratch.append(np.zeros(3_000, np.uint8))  # buffered: fails only when flushed
drop_all(made)
"""


def test_a_scratch_file_that_cannot_flush_is_still_removed(tmp_path: Path) -> None:
    """A scratch file whose last records are still buffered when the disk is full (here a
    real file size limit) is removed all the same, with every other one."""
    done = subprocess.run(
        [sys.executable, "-c", _DROP_CHILD, str(tmp_path / "c.copc.laz")],
        capture_output=True, text=True, preexec_fn=_limit_file_size, timeout=60,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert list(tmp_path.iterdir()) == []
