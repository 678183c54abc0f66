"""`acq sim` and `acq replay` warn, one line, when told to serve on every interface."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from acq.cli import main

WARNING = "listening on every network interface; the device is reachable from the network"


def test_replay_warns_of_every_interface(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    missing = str(tmp_path / "none.mcap")  # the warning comes first, then the log's error
    assert main(["replay", missing, "--listen", "tcp://0.0.0.0:10940"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert (
        err[0] == f"acq replay: warning: --listen tcp://0.0.0.0:10940: {WARNING}, without "
        "authentication"
    )
    assert len(err) == 2 and "none.mcap" in err[1]
    assert main(["replay", missing, "--camera-listen", "http://[::]:8080/stream.mjpg"]) == 2
    assert "--camera-listen http://[::]:8080/stream.mjpg: " + WARNING in capsys.readouterr().err
    assert main(["replay", missing, "--listen", "tcp://127.0.0.1:10940"]) == 2
    assert "warning" not in capsys.readouterr().err


def test_sim_scanner_warns_of_every_interface(capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket() as taken:  # the port is taken: the server fails after the warning
        taken.bind(("0.0.0.0", 0))
        taken.listen()
        port = taken.getsockname()[1]
        argv = ["sim", "scanner", "--model", "utm-30lx", "--listen", f"tcp://0.0.0.0:{port}"]
        assert main(argv) == 1
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith(f"acq sim scanner: warning: --listen tcp://0.0.0.0:{port}: {WARNING}")
    assert len(err) == 2 and "in use" in err[1]
