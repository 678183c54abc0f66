"""The processes a bench runs beside itself (``acq sim ...``, ``acq record``): the command
that runs ``acq``, waiting for the line a process prints when it is ready, ending it."""

from __future__ import annotations

import contextlib
import select
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import IO, Any

START_TIMEOUT_S = 60.0  # a cold start builds the street and compiles with numba


def acq_command() -> list[str]:
    """How to run ``acq``: the venv's script beside this Python, else ``-m acq.cli``."""
    exe = Path(sys.executable).with_name("acq")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "acq.cli"]


def wait_line(proc: subprocess.Popen[str], marker: str, timeout_s: float = START_TIMEOUT_S) -> str:
    """The first stdout line of ``proc`` holding ``marker``; RuntimeError after
    ``timeout_s`` or when the process ends first."""
    assert proc.stdout is not None
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and proc.poll() is None:
        ready, _, _ = select.select([proc.stdout], [], [], 0.5)
        if ready:
            line = proc.stdout.readline()
            if marker in line:
                return line
    raise RuntimeError(f"{' '.join(map(str, proc.args))}: no {marker!r} within {timeout_s:g} s")


def start_simulator(
    cmd: list[str], marker: str, stderr: IO[str] | Any
) -> tuple[subprocess.Popen[str], str]:
    """Run a simulator command; (the process, the URL it prints after ``marker``, which
    ends in `` on URL``)."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=stderr, text=True)
    try:
        line = wait_line(proc, marker)
    except RuntimeError:
        end(proc)
        raise
    return proc, line.rsplit(" on ", 1)[1].strip()


def end(proc: subprocess.Popen[str]) -> None:
    """Terminate ``proc`` (resumed first if it was stopped), killed after 5 s."""
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            proc.send_signal(signal.SIGCONT)
        proc.terminate()
        try:
            proc.wait(5.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    if proc.stdout is not None:
        proc.stdout.close()
