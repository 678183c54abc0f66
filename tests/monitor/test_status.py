"""`acq status` against a real `acq record --live` of the simulated rig (the UTM-30LX
speaking SCIP on TCP, the fisheye over HTTP MJPEG in its own process), from the log it
writes and from its live server (HOST:PORT): the --json while the recorder runs, the
full-screen view through a pseudo-terminal, a required scanner that stops, a finished
log, and no log."""

from __future__ import annotations

import json
import os
import pty
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml

from acq.cli.record import DEFAULT_ADDRESS
from acq.record.recorder import Recorder
from tests.sim_rig import Rig, warm_rig

ROOT = Path(__file__).resolve().parents[2]


def _status(*args: str | Path, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "acq.cli", "status", *map(str, args)],
        cwd=ROOT, capture_output=True, text=True, timeout=timeout,
    )  # fmt: skip


def _config(rig: Rig, tmp_path: Path) -> Path:
    """The rig's configuration with the scanner required."""
    cfg = rig.config(tmp_path)
    assert cfg.source is not None
    data = yaml.safe_load(cfg.source.read_text())
    data["scanners"][0]["required"] = True
    cfg.source.write_text(yaml.safe_dump(data))
    return cfg.source


@pytest.fixture(scope="module")
def rig() -> Iterator[Rig]:
    yield from warm_rig()


@dataclass
class Recording:
    logs: Path  # the output folder
    proc: subprocess.Popen[bytes]  # the recorder
    address: str  # its live server, HOST:PORT


def _free(address: str) -> bool:
    host, _, port = address.rpartition(":")
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the server binds
        try:
            s.bind((host, int(port)))
        except OSError:
            return False
        return True


def free_port() -> int:
    """A TCP port of 127.0.0.1 nothing listens on (as of now)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


@pytest.fixture(scope="module")
def recording(rig: Rig, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Recording]:
    """`acq record` of the rig running, once the recorder has reported its devices."""
    tmp = tmp_path_factory.mktemp("recording")
    # --live's default address when free: `acq status` without an argument finds it
    address = DEFAULT_ADDRESS if _free(DEFAULT_ADDRESS) else f"127.0.0.1:{free_port()}"
    proc = subprocess.Popen(
        [sys.executable, "-m", "acq.cli", "record", "-c", str(_config(rig, tmp)),
         "--duration", "120", "--live", address],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    logs = tmp / "logs"
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            time.sleep(0.5)
            done = _status(logs, "--json") if logs.is_dir() and any(logs.glob("*.mcap")) else None
            if done is not None and done.stdout and len(json.loads(done.stdout)["devices"]) == 2:
                break
        time.sleep(2.0)  # the rates settle over a few seconds of records
        yield Recording(logs, proc, address)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(20)


@pytest.mark.realtime
def test_json_of_a_running_recorder(recording: Recording) -> None:
    done = _status(recording.logs, "--json")
    assert done.returncode == 0 and done.stderr == "", done.stdout + done.stderr
    snap = json.loads(done.stdout)
    assert snap["writing"] and snap["ok"] and snap["problems"] == []
    assert Path(snap["file"]).parent == recording.logs and snap["file"].endswith("_000.mcap")
    assert snap["file_bytes"] > 0 and snap["write_rate_bps"] > 0
    assert 0 < snap["disk_minutes_left"]
    devices = {d["name"]: d for d in snap["devices"]}
    assert set(devices) == {"laser", "camera"}
    assert devices["laser"]["required"] and not devices["camera"]["required"]
    assert abs(devices["laser"]["rate_hz"] - 40.0) < 4.0  # the UTM-30LX's 40 Hz
    assert abs(devices["camera"]["rate_hz"] - 25.0) < 4.0  # the configured 25 fps
    assert all(d["connected"] and d["gap_s"] < 5.0 for d in devices.values())
    assert snap["time_base"].startswith("host clock")
    assert "colouring" not in snap  # this recorder colours nothing live


@pytest.mark.realtime
def test_json_of_a_running_recorder_from_its_live_server(recording: Recording) -> None:
    done = _status(recording.address, "--json")
    assert done.returncode == 0 and done.stderr == "", done.stdout + done.stderr
    snap = json.loads(done.stdout)
    assert snap["source"] == f"live ws://{recording.address}"
    assert snap["writing"] and snap["ok"] and snap["problems"] == []
    # the recorder's figures: its file's name (not its size), its disk
    assert snap["file"].endswith("_000.mcap") and snap["file_bytes"] is None
    assert snap["disk_free_bytes"] > 0 and 0 < snap["disk_minutes_left"]
    assert 0 <= snap["status_age_s"] < 2.0
    devices = {d["name"]: d for d in snap["devices"]}
    assert set(devices) == {"laser", "camera"}
    # required: the recorder's own flag in its status (no configuration read here)
    assert devices["laser"]["required"] and not devices["camera"]["required"]
    assert abs(devices["laser"]["rate_hz"] - 40.0) < 4.0
    assert abs(devices["camera"]["rate_hz"] - 25.0) < 4.0
    assert all(d["connected"] and d["gap_s"] < 5.0 for d in devices.values())
    assert snap["time_base"].startswith("host clock")
    assert "colouring" not in snap  # this recorder colours nothing live


@pytest.mark.realtime
def test_without_an_argument_the_live_server_on_this_host_is_shown(
    recording: Recording, tmp_path: Path
) -> None:
    if recording.address != DEFAULT_ADDRESS and _free(DEFAULT_ADDRESS):
        # this module's recorder of the other pytest-xdist worker had it, and has stopped
        pytest.skip(f"{DEFAULT_ADDRESS} was taken: the recorder serves another port")
    done = subprocess.run(
        [sys.executable, "-m", "acq.cli", "status", "--json"], cwd=tmp_path,
        capture_output=True, text=True, timeout=60, env={**os.environ, "PYTHONPATH": str(ROOT)},
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    snap = json.loads(done.stdout)
    assert snap["source"] == f"live ws://{DEFAULT_ADDRESS}"
    assert {d["name"] for d in snap["devices"]} == {"laser", "camera"}


def _view_through_pty(target: str, signum: signal.Signals) -> bytes:
    """`acq status TARGET` in a pseudo-terminal until it shows both devices, then
    ``signum``: all it wrote; asserts it ended with exit 0 and the terminal given back."""
    main, side = pty.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "acq.cli", "status", target],
        cwd=ROOT, stdin=side, stdout=side, stderr=subprocess.PIPE,
        env={**os.environ, "COLUMNS": "120", "LINES": "40", "TERM": "xterm"},
    )  # fmt: skip
    # the side stays open here until all is read: closed by its last holder, a pty's
    # master may say EIO before the last bytes written are read (lost, on a loaded host)
    seen = bytearray()
    ended = threading.Event()

    def read() -> None:  # all the view writes, while it runs and as it ends
        while True:
            if select.select([main], [], [], 0.2)[0]:
                seen.extend(os.read(main, 65536))
            elif ended.is_set():  # the process gone, and nothing more for 0.2 s
                return

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not (b"laser" in seen and b"camera" in seen):
            time.sleep(0.1)
        assert b"laser" in seen and b"camera" in seen, bytes(seen[-2000:])
        assert b"\x1b[?1049h" in seen  # the alternate screen: a full-screen view
        proc.send_signal(signum)
        assert proc.wait(10) == 0, proc.stderr.read() if proc.stderr else ""
        ended.set()
        reader.join(10)
        assert not reader.is_alive()
        assert seen.rfind(b"\x1b[?1049l") > seen.rfind(b"\x1b[?1049h")  # screen given back
        return bytes(seen)
    finally:
        if proc.poll() is None:
            proc.kill()
        ended.set()
        reader.join(10)
        os.close(side)
        os.close(main)


@pytest.mark.realtime
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_the_full_screen_view_through_a_pseudo_terminal(
    recording: Recording, signum: signal.Signals
) -> None:
    """Ctrl-C, or a SIGTERM (the terminal's window closed, a kill), ends the view with the
    terminal given back: the alternate screen left, exit 0."""
    _view_through_pty(str(recording.logs), signum)


@pytest.mark.realtime
def test_the_full_screen_view_of_a_live_server(recording: Recording) -> None:
    seen = _view_through_pty(recording.address, signal.SIGINT)
    assert f"live ws://{recording.address}".encode() in seen
    assert b"colouring" not in seen


def _until(
    logs: Path, named: str, within_s: float
) -> tuple[subprocess.CompletedProcess[str], float]:
    """`acq status --json --stale-s 2` until a problem names the device ``named`` (or
    ``within_s`` passes), and how long that took, s."""
    start = time.monotonic()
    while True:
        done = _status(logs, "--json", "--stale-s", "2")
        problems = json.loads(done.stdout)["problems"] if done.stdout else []
        if any(p.startswith(f"{named}:") for p in problems) or time.monotonic() - start > within_s:
            return done, time.monotonic() - start
        time.sleep(0.3)


@pytest.mark.realtime
def test_a_silent_camera_then_a_stopped_required_scanner_exit_1(
    rig: Rig, recording: Recording
) -> None:
    assert rig.camera is not None
    rig.camera.freeze()  # connected, but silent: nothing sent
    try:
        done, took = _until(recording.logs, "camera", 20)
    finally:
        rig.camera.thaw()
    assert done.returncode == 1, done.stdout + done.stderr
    # after --stale-s of silence, within the recorder's 1 s status and a loaded machine's
    # slack
    assert 2 <= took < 2 + 6
    snap = json.loads(done.stdout)
    assert [p.split(":")[0] for p in snap["problems"]] == ["camera"]
    assert "no record for" in snap["problems"][0]
    rig.scanner_server.close()  # the last test of the module to use the scanner
    done, took = _until(recording.logs, "laser", 20)
    assert done.returncode == 1, done.stdout + done.stderr
    assert took < 2 + 6  # a required device disconnected: at once
    assert not json.loads(done.stdout)["ok"]
    # the recording finished with its scanner down: its last state says so
    recording.proc.send_signal(signal.SIGTERM)
    recording.proc.wait(20)
    done = _status(recording.logs, "--json", "--stale-s", "2")
    snap = json.loads(done.stdout)
    assert done.returncode == 1 and snap["closed"] and not snap["writing"]
    assert any(p.startswith("laser:") for p in snap["problems"])


@pytest.mark.realtime
def test_a_finished_log_shows_its_last_state(tmp_path: Path) -> None:
    rig = Rig(cameras=())
    try:
        cfg = rig.config(tmp_path)
        assert Recorder(cfg, duration_s=3.0).run() == 0
    finally:
        rig.close()
    (log,) = (tmp_path / "logs").glob("*.mcap")
    done = _status(log, "--json")
    assert done.returncode == 0 and done.stderr == "", done.stdout + done.stderr
    snap = json.loads(done.stdout)
    assert snap["disk_minutes_left"] is None  # nothing is being written
    assert not snap["writing"] and snap["closed"] and snap["ok"] and snap["file"] == str(log)
    assert [d["name"] for d in snap["devices"]] == ["laser"]
    plain = _status(tmp_path / "logs")  # stdout a pipe: one plain snapshot
    assert plain.returncode == 0 and "finished, not being written" in plain.stdout
    assert "laser" in plain.stdout and "\x1b[" not in plain.stdout


def test_no_log_is_one_line_and_exit_2(tmp_path: Path) -> None:
    done = _status(tmp_path, "--json")
    assert done.returncode == 2
    assert done.stdout == ""
    assert done.stderr.strip().splitlines() == [
        f"acq status: {tmp_path}: no .mcap log in this folder"
    ]
    done = _status(tmp_path / "missing.mcap")
    assert done.returncode == 2 and "missing.mcap: no such log or folder" in done.stderr


def test_the_commands_staleness_default_is_the_snapshots() -> None:
    """`acq status --stale-s` defaults to what the snapshot judges by (the parser keeps its
    own literal: importing acq.monitor.snapshot to build it costs 0.4 s on every command)."""
    from acq.cli.main import build_parser
    from acq.monitor.snapshot import STALE_S

    args = build_parser().parse_args(["status", "log.mcap"])
    assert args.stale_s == STALE_S
