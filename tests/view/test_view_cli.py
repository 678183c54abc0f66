"""`acq view` on the command line: it serves until Ctrl-C (exit 0), opens the browser
when asked, and refuses a bad file or option in one line with exit status 2."""

from __future__ import annotations

import ctypes
import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from acq.cli import main
from tests.view.layer_files import cloud, las_cloud, mesh


def _refused(capsys: pytest.CaptureFixture[str], argv: list[str], *named: str) -> str:
    """Runs `acq view ARGV`, expecting exit status 2 and one line naming ``named``."""
    assert main(["view", *argv]) == 2
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("acq view: "), captured.err
    assert all(n in lines[0] for n in named), lines[0]
    assert captured.out == ""
    return lines[0]


def test_bad_files_are_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    good = cloud(tmp_path / "good.ply")
    _refused(capsys, [str(good), str(tmp_path / "gone.glb")], "gone.glb", "No such file")
    (tmp_path / "empty").mkdir()
    _refused(capsys, [str(tmp_path / "empty")], "empty: a folder with no .ply, .glb, .las")
    short = tmp_path / "short.ply"
    short.write_bytes(good.read_bytes()[:-100])
    _refused(capsys, [str(short)], "short.ply", "PLY")
    garbage = tmp_path / "garbage.glb"
    garbage.write_bytes(os.urandom(300))
    _refused(capsys, [str(garbage)], "garbage.glb", "glTF")
    short_glb = tmp_path / "short.glb"
    short_glb.write_bytes(mesh(tmp_path / "m.glb").read_bytes()[:-1])
    _refused(capsys, [str(short_glb)], "short.glb", "bytes")
    # nothing written beside the inputs
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["good.ply", "empty", "short.ply", "garbage.glb", "short.glb", "m.glb"]
    )


def test_bad_las_files_and_max_points_are_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    laz, _, _ = las_cloud(tmp_path / "good.laz", n=20_000)
    garbage = tmp_path / "garbage.las"
    garbage.write_bytes(os.urandom(400))
    _refused(capsys, [str(garbage)], "garbage.las", "LAS")
    for bad in ("0", "-5", "1.5", "x"):
        _refused(capsys, [str(laz), "--max-points", bad], "--max-points", bad)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["garbage.las", "good.laz"]


@pytest.mark.parametrize("port", ["nan", "-1", "65536", "1e3", "99999999999999999999", "x"])
def test_bad_ports_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], port: str
) -> None:
    _refused(capsys, [str(cloud(tmp_path / "c.ply", n=5)), "--port", port], "--port", port)


def test_a_port_in_use_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        line = _refused(capsys, [str(cloud(tmp_path / "c.ply", n=5)), "--port", str(port)])
    assert line == f"acq view: --port {port}: in use on 127.0.0.1 (another server listens there)"


def test_another_host_is_warned_of_and_a_foreign_address_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = str(cloud(tmp_path / "c.ply", n=5))
    # 192.0.2.1 (TEST-NET-1, RFC 5737) is no address of this machine
    assert main(["view", path, "--host", "192.0.2.1"]) == 2
    warning, refusal = capsys.readouterr().err.splitlines()
    assert warning.startswith("acq view: warning: --host 192.0.2.1: the files are served")
    assert refusal == "acq view: --host 192.0.2.1: not an address of this machine"
    _refused(capsys, [path, "--host", "::1", "--port", "-5"], "--port")  # no warning for ::1


def _stopped(
    proc: subprocess.Popen[str], signum: int = signal.SIGINT, *, tid: int | None = None
) -> tuple[str, str]:
    """Ctrl-C (or ``signum``) to ``proc`` (an `acq view` started with :data:`DUMPS`), or
    to its thread ``tid`` only: its (stdout, stderr) once it exits; when it does not within
    20 s, fails saying its state, its children and every thread's stack (faulthandler's
    dump on SIGABRT) to say where it hung."""
    if tid is None:
        proc.send_signal(signum)
    elif ctypes.CDLL(None, use_errno=True).tgkill(proc.pid, tid, signum) != 0:
        raise OSError(ctypes.get_errno(), f"tgkill {proc.pid} {tid}")
    try:
        return proc.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        status = Path(f"/proc/{proc.pid}/status").read_text().splitlines()
        state = [line for line in status if line.startswith(("State", "Threads", "Sig", "Shd"))]
        children = [line for line in map(_stat, Path("/proc").glob("[0-9]*/stat"))
                    if line.rpartition(")")[2].split()[1:2] == [str(proc.pid)]]  # fmt: skip
        proc.send_signal(signal.SIGABRT)
        try:
            err = proc.communicate(timeout=20)[1]
        except subprocess.TimeoutExpired:
            err = "(its pipes still open: held by a child?)"
        pytest.fail(
            f"acq view did not exit within 20 s of Ctrl-C ({state}; children {children});"
            f" its threads:\n{err}"
        )


def _stat(path: Path) -> str:
    """A process's /proc stat line ("" once it is gone)."""
    try:
        return path.read_text()
    except OSError:
        return ""


DUMPS = os.environ | {"PYTHONFAULTHANDLER": "1"}  # a stack dump on SIGABRT


def test_serves_until_ctrl_c_and_opens_the_browser(tmp_path: Path) -> None:
    path = cloud(tmp_path / "c.ply", n=50)
    # the "browser": a command that writes down the URL it is given (webbrowser's BROWSER)
    opened = tmp_path / "opened.txt"
    browser = tmp_path / "browser.sh"
    browser.write_text(f'#!/bin/sh\necho "$1" > {opened}\n')
    browser.chmod(0o755)
    proc = subprocess.Popen(
        [sys.executable, "-m", "acq.cli", "view", str(path), "--open"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env=DUMPS | {"BROWSER": f"{browser} %s"},
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.startswith("serving 1 layer at http://127.0.0.1:"), line
        url = line.split(" at ")[1].split()[0]
        with urllib.request.urlopen(f"{url}api/layers", timeout=10) as r:
            assert json.loads(r.read())[0]["name"] == "c.ply"
        deadline = time.monotonic() + 20
        while not opened.exists() and time.monotonic() < deadline:  # the browser runs apart
            time.sleep(0.05)
        out, err = _stopped(proc)
    finally:
        proc.kill()
    assert proc.returncode == 0 and err == "" and out == ""
    assert opened.read_text().strip() == url


def test_points_found_bad_after_the_url_is_printed_are_said_in_one_line(tmp_path: Path) -> None:
    laz, _, _ = las_cloud(tmp_path / "good.laz", n=20_000)
    cut = tmp_path / "cut.laz"  # its header whole: refused only when its points are decoded
    cut.write_bytes(laz.read_bytes()[: laz.stat().st_size // 2])
    proc = subprocess.Popen(
        [sys.executable, "-m", "acq.cli", "view", str(laz), str(cut)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=DUMPS,
    )  # fmt: skip
    try:
        assert proc.stdout is not None and proc.stderr is not None
        assert proc.stdout.readline().startswith("serving 2 layers at http://127.0.0.1:")
        said = proc.stderr.readline()  # while it keeps serving the good one
        out, err = _stopped(proc)
    finally:
        proc.kill()
    assert said.startswith(f"acq view: {cut}: its points cannot be read ("), said
    assert proc.returncode == 0 and err == "" and out == ""


def test_ctrl_c_taken_by_another_thread_than_the_main_one_stops_it(tmp_path: Path) -> None:
    """The kernel gives a process's signal to any of its threads that does not block it:
    one taken by the server's thread (or a library's) stops acq view as well."""
    path = cloud(tmp_path / "c.ply", n=50)
    proc = subprocess.Popen(
        [sys.executable, "-m", "acq.cli", "view", str(path)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=DUMPS,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().startswith("serving 1 layer at http://127.0.0.1:")
        others = [int(t.name) for t in Path(f"/proc/{proc.pid}/task").iterdir()]
        others.remove(proc.pid)
        assert others, "acq view serves from a thread of its own"
        out, err = _stopped(proc, tid=max(others))
    finally:
        proc.kill()
    assert proc.returncode == 0 and err == "" and out == ""


def _sigint_ignored() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_a_signal_stops_it_even_started_with_sigint_ignored(tmp_path: Path, signum: int) -> None:
    """A script's background job starts with SIGINT ignored, and Python then leaves Ctrl-C
    without effect: acq view still ends on it, and on SIGTERM and SIGHUP, with status 0."""
    path = cloud(tmp_path / "c.ply", n=50)
    proc = subprocess.Popen(
        [sys.executable, "-m", "acq.cli", "view", str(path)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=DUMPS,
        preexec_fn=_sigint_ignored,  # as `cmd &` in a non-interactive shell
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().startswith("serving 1 layer at http://127.0.0.1:")
        out, err = _stopped(proc, signum)
    finally:
        proc.kill()
    assert proc.returncode == 0 and err == "" and out == ""
