"""`acq sim camera` as its own process and `acq probe camera` reading it over HTTP."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
from pathlib import Path

import cv2
import pytest

from acq import cli

# drives simulated devices in real time: run alone (`make test`)
pytestmark = pytest.mark.realtime


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_probe_camera_reads_the_simulated_camera_at_25_hz(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    url = f"http://127.0.0.1:{free_port()}/stream.mjpg"
    proc = subprocess.Popen(
        [sys.executable, "-m", "acq.cli", "sim", "camera", "--listen", url, "--still"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline()
        assert url in first, first + (proc.stderr.read() if proc.stderr else "")
        snap = tmp_path / "snap.png"
        code = cli.main(["probe", "camera", "--driver", "opencv", "--source", url,
                         "--count", "30", "--json", "--snapshot", str(snap)])  # fmt: skip
        out = capsys.readouterr()
        assert code == 0, out.err
        lines = [json.loads(line) for line in out.out.splitlines()]
        device, frames, summary = lines[0]["device"], lines[1:-1], lines[-1]["summary"]
        assert (device["width"], device["height"]) == (780, 582)
        assert len(frames) == 30
        assert all(f["jpeg_bytes"] > 10_000 for f in frames)
        assert summary["drops"] == 0 and summary["corrupt"] == 0
        # from receipts: a loaded host delays the first or the last (26.4 Hz measured once
        # beside two busy loops and the other tests)
        assert summary["rate_hz"] == pytest.approx(25.0, rel=0.1)
        assert cv2.imread(str(snap)).shape == (582, 780, 3)
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(10) == 0


def test_probe_camera_reports_an_unreachable_source(capsys: pytest.CaptureFixture[str]) -> None:
    """Naming the source without its password."""
    where = f"127.0.0.1:{free_port()}/stream.mjpg"
    url = f"http://admin:S3CRET@{where}"
    assert cli.main(["probe", "camera", "--driver", "opencv", "--source", url, "--count", "1",
                     "--timeout", "0.5"]) == 1  # fmt: skip
    err = capsys.readouterr().err
    assert f"http://***@{where}" in err and "S3CRET" not in err
