"""Temporaries of writers that died: a temporary is locked by the process that made it
for that process's life, so the next run removes those whose writer is dead and leaves
those of a writer still at work (two commands may write one output at once). The
writers here are real processes, holding real locks on real files; SIGKILL ends them."""

from __future__ import annotations

import logging
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from acq.atomic_write import release, remove_stale, temporary_beside

# a writer that takes a temporary beside argv[1] (a folder when argv[2] is "folder"),
# writes into it, says its name and waits to be killed
_WRITER = """
import sys, time
from pathlib import Path
from acq.atomic_write import temporary_beside
tmp = temporary_beside(Path(sys.argv[1]), suffix="" if sys.argv[2] == "folder" else None,
                       folder=sys.argv[2] == "folder")
if tmp.is_dir():
    (tmp / "metadata.yaml").write_text("half a bag")
else:
    with open(tmp, "r+b") as f:
        f.write(b"half a cloud")
print(tmp, flush=True)
time.sleep(60)
"""


def _writer(output: Path, kind: str = "file") -> tuple[subprocess.Popen[str], Path]:
    proc = subprocess.Popen([sys.executable, "-c", _WRITER, str(output), kind],
                            stdout=subprocess.PIPE, text=True)  # fmt: skip
    assert proc.stdout is not None
    return proc, Path(proc.stdout.readline().strip())


def _kill(proc: subprocess.Popen[str]) -> None:
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=10)
    if proc.stdout is not None:
        proc.stdout.close()


@pytest.mark.parametrize("kind", ["file", "folder"])
def test_a_killed_writers_temporary_is_removed_by_the_next_run_a_live_ones_kept(
    tmp_path: Path, kind: str, caplog: pytest.LogCaptureFixture
) -> None:
    out = tmp_path / ("bag" if kind == "folder" else "c.laz")
    suffix = "" if kind == "folder" else None
    live, live_tmp = _writer(out, kind)
    dead, dead_tmp = _writer(out, kind)
    try:
        _kill(dead)  # SIGKILL: no handler ran, the temporary is there
        assert dead_tmp.exists() and live_tmp.exists()
        with caplog.at_level(logging.WARNING, logger="acq.atomic_write"):
            removed = remove_stale(out, suffix)
        assert removed == [dead_tmp] and not dead_tmp.exists()
        assert live_tmp.exists()  # its writer still holds it
        assert caplog.messages == [
            f"removed a stale temporary {dead_tmp} left by a run that was killed"
        ]
        # the next writer of the output cleans up too; its own temporary is not stale
        mine = temporary_beside(out, suffix, folder=kind == "folder")
        assert mine.exists() and remove_stale(out, suffix) == []
        mine.rmdir() if mine.is_dir() else mine.unlink()
        release(mine)
    finally:
        _kill(live)
    assert remove_stale(out, suffix) == [live_tmp]


def test_only_the_outputs_own_temporaries_are_touched(tmp_path: Path) -> None:
    """Other outputs' temporaries and the user's files that look alike are left."""
    out = tmp_path / "c.ply"
    proc, dead_tmp = _writer(out)
    _kill(proc)
    names = (".c.0123abcd.tmp.laz", ".cc.0123abcd.tmp.ply", ".c.0123abcd.tmp.ply.keep",
             ".c.notours1.tmp.ply", "c.ply")  # fmt: skip
    others = [tmp_path / n for n in names]
    for p in others:
        p.write_bytes(b"x")
    assert remove_stale(out) == [dead_tmp]
    assert sorted(tmp_path.iterdir()) == sorted(others)


def test_a_temporary_is_created_locked_and_released_once_renamed(tmp_path: Path) -> None:
    out = tmp_path / "c.ply"
    tmp = temporary_beside(out)
    assert tmp.exists() and tmp.stat().st_size == 0
    # another process cannot take its lock while this one lives
    probe = ("import fcntl, os, sys; fd = os.open(sys.argv[1], os.O_RDONLY)\n"
             "try: fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)\n"
             "except BlockingIOError: sys.exit(7)")  # fmt: skip
    held = subprocess.run([sys.executable, "-c", probe, str(tmp)], timeout=30)
    assert held.returncode == 7
    tmp.replace(out)
    release(tmp)
    free = subprocess.run([sys.executable, "-c", probe, str(out)], timeout=30)
    assert free.returncode == 0
