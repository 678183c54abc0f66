"""How `acq record` ends, against a simulated UTM-30LX on TCP (127.0.0.1), its files read
back with the `mcap` seeking reader: every signal that would end the process but SIGKILL,
the faults and the watchdog's SIGABRT finishes the file, SIGHUP included (a terminal on a
pseudo-terminal that is hung up, as when an ssh link drops); a recording with its stdout
closed exits 0, its file not on descriptor 1."""

from __future__ import annotations

import logging
import os
import pty
import select
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml
from mcap.exceptions import McapError
from mcap.reader import make_reader

from acq.record import config as configfile
from acq.record.recorder import record
from acq.sim.transport import TcpDeviceServer

# drives a simulated scanner in real time: run alone (`make test`)
pytestmark = pytest.mark.realtime

ROOT = Path(__file__).resolve().parents[2]

# signal(7): the signals whose default action ends the process ("Term" and "Core")
ENDING = {"SIGABRT", "SIGALRM", "SIGBUS", "SIGFPE", "SIGHUP", "SIGILL", "SIGINT", "SIGIO",
          "SIGKILL", "SIGPIPE", "SIGPROF", "SIGPWR", "SIGQUIT", "SIGSEGV", "SIGSTKFLT",
          "SIGSYS", "SIGTERM", "SIGTRAP", "SIGUSR1", "SIGUSR2", "SIGVTALRM", "SIGXCPU",
          "SIGXFSZ"}  # fmt: skip
# ...of which these are left to their default: uncatchable, the process's own faults, the
# watchdog's abort (its stack dump), and the two Python ignores (the write fails instead)
DEFAULT = {"SIGKILL", "SIGSEGV", "SIGBUS", "SIGILL", "SIGFPE", "SIGABRT", "SIGPIPE", "SIGXFSZ"}
DEFAULT_HANDLERS = {signal.SIG_DFL, signal.SIG_IGN, signal.default_int_handler, None}


def write_config(tmp_path: Path, scanner: TcpDeviceServer) -> Path:
    data = {
        "version": 1,
        "scanners": [{"name": "laser", "driver": "hokuyo", "url": scanner.url}],
        "output": {"dir": str(tmp_path / "logs")},
    }
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def closed_scans(folder: Path) -> int:
    """The scans of the one file in ``folder``, counted in its summary: a file that was
    not closed has none (the seeking reader needs its footer)."""
    (path,) = sorted(folder.glob("*.mcap"))
    with path.open("rb") as f:
        try:
            summary = make_reader(f).get_summary()
        except McapError as e:  # no footer where the seeking reader looks for it
            raise AssertionError(f"{path}: not closed ({e})") from None
    assert summary is not None and summary.statistics is not None, f"{path}: not closed"
    ids = [c.id for c in summary.channels.values() if c.topic == "/laser/scan"]
    return sum(summary.statistics.channel_message_counts.get(i, 0) for i in ids)


def wait_for_scans(folder: Path, proc: subprocess.Popen[bytes], timeout_s: float = 30.0) -> None:
    """Until the recording in ``folder`` has a file and the recorder a few seconds of scans."""
    deadline = time.monotonic() + timeout_s
    while not list(folder.glob("*.mcap")):
        assert proc.poll() is None, "the recorder ended before its file"
        assert time.monotonic() < deadline, "no file"
        time.sleep(0.1)
    time.sleep(2.0)


# the child takes the terminal on its standard input as its controlling terminal, as a
# login shell's does, then becomes the recorder: the terminal's hang-up is its SIGHUP
AS_SESSION = (
    "import fcntl, os, sys, termios; fcntl.ioctl(0, termios.TIOCSCTTY, 0); "
    "os.execv(sys.executable, [sys.executable, '-m', 'acq.cli', *sys.argv[1:]])"
)


def test_a_terminal_that_goes_away_finishes_the_file(
    scanner: TcpDeviceServer, tmp_path: Path
) -> None:
    cfg = write_config(tmp_path, scanner)
    proc, master, said, stop, reader = in_terminal(
        [sys.executable, "-c", AS_SESSION, "record", "-c", str(cfg)], start_new_session=True
    )
    try:
        wait_for_scans(tmp_path / "logs", proc)
        stop.set()
        reader.join()  # no read holds the terminal open
        os.close(master)  # the ssh link drops: the kernel hangs the terminal up
        code = proc.wait(20)
    finally:
        proc.kill()
    text = said.decode(errors="replace")
    assert code == 0, text  # not -1: killed by the SIGHUP
    assert "recording laser" in text
    assert closed_scans(tmp_path / "logs") > 20


def in_terminal(
    argv: list[str], start_new_session: bool = False
) -> tuple[subprocess.Popen[bytes], int, bytearray, threading.Event, threading.Thread]:
    """``argv`` started on a new pseudo-terminal (its standard streams): the process, the
    terminal's master side, what it writes there (read on a thread until the event)."""
    master, tty = pty.openpty()
    try:
        proc = subprocess.Popen(
            argv, cwd=ROOT, stdin=tty, stdout=tty, stderr=tty,
            start_new_session=start_new_session,
        )  # fmt: skip
    finally:
        os.close(tty)
    said, stop = bytearray(), threading.Event()
    reader = threading.Thread(target=read_terminal, args=(master, said, stop), daemon=True)
    reader.start()
    return proc, master, said, stop, reader


def read_terminal(fd: int, into: bytearray, stop: threading.Event) -> None:
    """What the recorder writes to its terminal, until ``stop``."""
    while not stop.is_set():
        if select.select([fd], [], [], 0.05)[0]:
            try:
                into += os.read(fd, 65536)
            except OSError:  # EIO: the recorder is gone
                return


def test_sigusr1_finishes_the_file(scanner: TcpDeviceServer, tmp_path: Path) -> None:
    cfg = write_config(tmp_path, scanner)
    proc = subprocess.Popen(
        [sys.executable, "-m", "acq.cli", "record", "-c", str(cfg)],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
    )  # fmt: skip
    try:
        wait_for_scans(tmp_path / "logs", proc)
        proc.send_signal(signal.SIGUSR1)
        _, err = proc.communicate(timeout=20)
    finally:
        proc.kill()
    text = err.decode(errors="replace")
    assert proc.returncode == 0, text
    assert "SIGUSR1: finishing the file" in text
    assert closed_scans(tmp_path / "logs") > 20


def test_every_signal_that_would_end_the_recorder_finishes_the_file(
    scanner: TcpDeviceServer, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    cfg = configfile.load(write_config(tmp_path, scanner))
    rt = int(signal.SIGRTMIN) + 3
    seen: dict[str, object] = {}

    def while_recording() -> None:  # look at the handlers, then end it with a real-time one
        deadline = time.monotonic() + 30.0
        while not list((tmp_path / "logs").glob("*.mcap")) and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(1.0)
        for name in ENDING - DEFAULT:
            seen[name] = signal.getsignal(getattr(signal, name))
        for s in range(signal.SIGRTMIN, signal.SIGRTMAX + 1):
            seen[f"SIGRTMIN+{s - signal.SIGRTMIN}"] = signal.getsignal(s)
        for name in DEFAULT:
            seen[name] = signal.getsignal(getattr(signal, name))
        if seen["SIGRTMIN+3"] not in DEFAULT_HANDLERS:  # else it would end pytest
            os.kill(os.getpid(), rt)

    before = {s: signal.getsignal(s) for s in signal.valid_signals()}
    threading.Thread(target=while_recording, daemon=True).start()
    with caplog.at_level(logging.INFO, logger="acq.record"):
        code = record(cfg, duration_s=8.0)  # the signal handlers need the main thread
    assert code == 0
    assert "SIGRTMIN+3: finishing the file" in caplog.text
    assert closed_scans(tmp_path / "logs") > 5
    finishing = {name for name, handler in seen.items() if handler not in DEFAULT_HANDLERS}
    expected = (ENDING - DEFAULT) | {n for n in seen if n.startswith("SIGRTMIN+")}
    assert finishing == expected
    assert {s: signal.getsignal(s) for s in signal.valid_signals()} == before  # put back


def test_a_closed_stdout_records_and_exits_0(scanner: TcpDeviceServer, tmp_path: Path) -> None:
    cfg = write_config(tmp_path, scanner)
    proc = subprocess.Popen(
        ["sh", "-c", 'exec "$@" >&-', "sh",  # the shell closes stdout, then is the recorder
         sys.executable, "-m", "acq.cli", "record", "-c", str(cfg), "--duration", "4"],
        cwd=ROOT, stderr=subprocess.PIPE,
    )  # fmt: skip
    try:
        wait_for_scans(tmp_path / "logs", proc)
        # descriptor 1 is /dev/null, not the next file opened (the log)
        stdout = os.readlink(f"/proc/{proc.pid}/fd/1")
        _, err = proc.communicate(timeout=20)
    finally:
        proc.kill()
    text = err.decode(errors="replace")
    assert proc.returncode == 0, text
    assert stdout == os.devnull
    assert "Traceback" not in text and "Error" not in text, text
    assert closed_scans(tmp_path / "logs") > 20


def test_a_terminal_shows_the_status_each_second_under_the_log_lines(
    scanner: TcpDeviceServer, tmp_path: Path
) -> None:
    """In a terminal the STATUS= text systemd gets is drawn on the last line each second,
    erased before a log line and drawn again after it; a file's end leaves it erased."""
    cfg = write_config(tmp_path, scanner)
    proc, master, said, stop, reader = in_terminal(
        [sys.executable, "-m", "acq.cli", "record", "-c", str(cfg), "--duration", "3.5"]
    )
    try:
        code = proc.wait(30)
        time.sleep(0.2)
    finally:
        stop.set()
        reader.join()
        os.close(master)
        proc.kill()
    text = said.decode(errors="replace")
    assert code == 0, text
    drawn = [part for part in text.split("\r\x1b[2K") if part.startswith("laser ")]
    assert len(drawn) >= 3, text  # about one a second, drawn again after log lines
    # down until the scanner is connected (on a busy machine that can take seconds), then
    # up to the end, with no drop
    up = [i for i, part in enumerate(drawn) if "Hz; drops 0" in part]
    assert up and up == list(range(up[0], len(drawn))), drawn
    assert all(part.startswith("laser 0.0 Hz (down); drops 0") for part in drawn[: up[0]]), drawn
    assert "INFO acq.record: stopped after" in text
    assert text.rstrip("\r\n").endswith("\r\x1b[2K"), repr(text[-200:])  # erased at the end


def test_status_asked_off_a_terminal_is_a_line_a_second(
    scanner: TcpDeviceServer, tmp_path: Path
) -> None:
    """Not a terminal (the journal has STATUS=): no status unless asked; ``--status``
    gives one plain line each second."""
    cfg = write_config(tmp_path, scanner)
    argv = [sys.executable, "-m", "acq.cli", "record", "-c", str(cfg), "--duration", "3.5"]
    done = subprocess.run([*argv, "--status"], capture_output=True, text=True, timeout=30)
    assert done.returncode == 0, done.stderr
    lines = [s for s in done.stderr.splitlines() if s.startswith("status: laser ")]
    assert len(lines) >= 2 and "\x1b" not in done.stderr, done.stderr
    quiet = subprocess.run(argv, capture_output=True, text=True, timeout=30)
    assert quiet.returncode == 0 and "status:" not in quiet.stderr, quiet.stderr
