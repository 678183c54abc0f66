"""Hokuyo's own clients for the tests: the urg_library sample programs built in
../shared/tools/vendor-clients/hokuyo/ (see its README), run with a bounded wait.

Their Ethernet samples connect to port 10940, fixed in their source (``SAMPLE_PORT``):
a test serving them listens there, so such tests take :func:`sample_port` first: one at a
time across the test workers (and any other run of the tests on this machine).
"""

from __future__ import annotations

import fcntl
import os
import selectors
import signal
import subprocess
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.conftest import SHARED

SAMPLES = SHARED / "tools" / "vendor-clients" / "hokuyo"
SAMPLE_PORT = 10940
ETHERNET = ["-e", "127.0.0.1"]


@contextmanager
def sample_port(timeout_s: float = 300.0) -> Iterator[None]:
    """Hold ``SAMPLE_PORT`` for this process: a lock file beside the machine's other
    temporary files, waited for up to ``timeout_s`` s (a test on another worker serving
    the samples)."""
    path = Path(tempfile.gettempdir()) / f"acq-tests-port-{SAMPLE_PORT}.lock"
    with open(path, "a") as lock:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError as e:
                if time.monotonic() > deadline:
                    held = f"port {SAMPLE_PORT} held by another test for {timeout_s} s"
                    raise TimeoutError(held) from e
                time.sleep(0.05)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def samples() -> Path:
    """The samples' folder; skips the test when it is absent."""
    if not (SAMPLES / "get_distance").is_file():
        pytest.skip(f"{SAMPLES} is absent: Hokuyo's urg_library samples are not built here")
    return SAMPLES


def serial(path: str) -> list[str]:
    """The samples' arguments for a serial port (a pty's path)."""
    return ["-s", path]


@dataclass(frozen=True)
class SampleRun:
    """What a sample printed (stdout and stderr, by line) and how it ended: its exit
    status, or None when it was killed after printing the lines asked for."""

    lines: list[str]
    returncode: int | None


def run_sample(
    name: str, target: list[str], *, lines: int | None = None, timeout_s: float = 10.0
) -> SampleRun:
    """Run sample ``name`` against ``target`` (``ETHERNET`` or ``serial(pty)``): until it
    exits, or, with ``lines``, until it printed that many lines and is then killed.
    Fails the test when it neither exits nor prints them within ``timeout_s``."""
    proc = subprocess.Popen(
        ["stdbuf", "-oL", str(samples() / name), *target],  # line by line, as it prints
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    assert proc.stdout is not None
    out = bytearray()
    deadline = time.monotonic() + timeout_s
    with selectors.DefaultSelector() as sel:
        sel.register(proc.stdout, selectors.EVENT_READ)
        try:
            while lines is None or out.count(b"\n") < lines:
                left = deadline - time.monotonic()
                if left <= 0:
                    pytest.fail(f"{name} {' '.join(target)}: no end after {timeout_s} s: {out!r}")
                if not sel.select(left):
                    continue
                chunk = os.read(proc.stdout.fileno(), 65536)
                if not chunk:
                    break  # it exited
                out += chunk
        finally:
            if proc.poll() is None:
                os.kill(proc.pid, signal.SIGKILL)
            code = proc.wait(5)
            proc.stdout.close()
    killed = code == -signal.SIGKILL
    text = out.decode("ascii", "replace").splitlines()
    return SampleRun(text[:lines] if killed and lines else text, None if killed else code)
