"""An output that does not fit on its disk: one line naming the output and the disk, exit
status 3 (as `acq record` at its disk reserve), no temporary left behind, whatever the
writing library makes of the failed write (lazrs: ``LazrsError: IoError``, libE57:
``E57Exception``, numpy: ``N requested and M written``).

A full file system cannot be made without root, so the commands run as real subprocesses
under a file size limit (RLIMIT_FSIZE): the kernel itself then refuses every write past
the limit (EFBIG, SIGXFSZ being ignored by Python), on real files, through the same calls
a full disk fails (ENOSPC); nothing in acq is mocked. Where a small tmpfs can be mounted
(root), one case also fills a real file system (skipped elsewhere)."""

from __future__ import annotations

import contextlib
import resource
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from acq.sim.drive_log import DriveTruth

LIMIT = 32 * 1024  # bytes a file may hold: less than any of the short drive's outputs


def _limited() -> None:
    resource.setrlimit(resource.RLIMIT_FSIZE, (LIMIT, LIMIT))


def _acq(*argv: str, limited: bool = True) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "acq.cli", *argv], capture_output=True,
                          text=True, timeout=120,
                          preexec_fn=_limited if limited else None)  # fmt: skip


@contextlib.contextmanager
def _small_tmpfs(folder: Path, kilobytes: int) -> Iterator[Path]:
    """``folder`` as a tmpfs of ``kilobytes``; skips the test where none can be mounted."""
    folder.mkdir()
    mount = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={kilobytes}k", "tmpfs",
                            str(folder)], capture_output=True, timeout=30)  # fmt: skip
    if mount.returncode != 0:
        pytest.skip(f"no tmpfs can be mounted here (not root?): {mount.stderr.decode().strip()}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", str(folder)], check=True, timeout=30)


def _said_full(err: str, output: Path, command: str) -> None:
    lines = [ln for ln in err.splitlines() if not ln.startswith(("note:", "warning:"))]
    line = next(ln for ln in lines if str(output) in ln)
    assert line.startswith(f"acq {command}: ")
    assert (
        f"{output}: too large for the disk of {output.parent} or the process's file size limit ("
        in line
        and line.endswith(" MB free)")
    ), err
    assert "a bug?" not in err and "Error" not in err


@pytest.mark.parametrize("name", ["c.laz", "c.las", "c.e57", "c.ply"])
def test_a_cloud_that_does_not_fit_is_one_line_exit_3_and_no_temporary(
    short_drive: tuple[DriveTruth, Path], tmp_path: Path, name: str
) -> None:
    truth, calib = short_drive
    out = tmp_path / name
    run = _acq("colorize", *map(str, truth.files), "--calib", str(calib), "-o", str(out),
               "--no-preview")  # fmt: skip
    assert run.returncode == 3, run.stderr
    _said_full(run.stderr, out, "colorize")
    assert list(tmp_path.iterdir()) == []  # neither the cloud nor its temporary


def test_a_bag_that_does_not_fit_is_one_line_exit_3_and_no_work_folder(
    short_drive: tuple[DriveTruth, Path], tmp_path: Path
) -> None:
    truth, _ = short_drive
    bag = tmp_path / "bag"
    run = _acq("export", "ros2", *map(str, truth.files), "-o", str(bag))
    assert run.returncode == 3, run.stderr
    _said_full(run.stderr, bag, "export ros2")
    assert list(tmp_path.iterdir()) == []


def test_any_file_a_command_writes_past_the_disk_is_the_same_line(
    short_drive: tuple[DriveTruth, Path], tmp_path: Path
) -> None:
    """A file error of a full disk that reaches the command line (here `info --repair`'s
    copy) is said the same way, exit status 3."""
    truth, _ = short_drive
    copy = tmp_path / "copy.mcap"
    run = _acq("info", "--repair", str(truth.files[0]), "-o", str(copy))
    assert run.returncode == 3, run.stderr
    _said_full(run.stderr, copy, "info")
    assert list(tmp_path.iterdir()) == []


def test_a_laz_on_a_really_full_disk(short_drive: tuple[DriveTruth, Path], tmp_path: Path) -> None:
    """lazrs's ``IoError: Failed to call write`` on a file system that is full (ENOSPC)."""
    truth, calib = short_drive
    with _small_tmpfs(tmp_path / "disk", 64) as disk:
        out = disk / "c.laz"
        run = _acq("colorize", *map(str, truth.files), "--calib", str(calib), "-o", str(out),
                   "--no-preview", limited=False)  # fmt: skip
        assert run.returncode == 3, run.stderr
        assert f"acq colorize: {out}: no space left on the disk of {disk} (0.0 MB free)" in (
            run.stderr.splitlines()
        )
        assert list(disk.iterdir()) == []


def test_a_library_error_is_the_disk_only_when_the_disk_says_so(tmp_path: Path) -> None:
    """An error without an error number (a library's own) is put down to the disk only
    when a write beside the output fails for want of room."""
    from acq.disk_space import full_disk_error
    from acq.errors import DiskFullError

    out = tmp_path / "c.laz"
    opaque = RuntimeError("IoError: Failed to call write")
    assert full_disk_error(out, opaque) is None  # the disk has room: not the disk
    full = full_disk_error(out, OSError(28, "No space left on device"))
    assert isinstance(full, DiskFullError)
    assert str(full).startswith(f"{out}: no space left on the disk of {tmp_path} (")
