"""The processes a bench runs beside itself (``acq sim ...``, ``acq record``): the command
that runs ``acq``, waiting for the line a process prints when it is ready, ending it; a
process's CPU time and memory from /proc; a recorder run (:class:`Run`)."""

from __future__ import annotations

import contextlib
import os
import re
import select
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

START_TIMEOUT_S = 60.0  # a cold start builds the street and compiles with numba
CLK_TCK = os.sysconf("SC_CLK_TCK")
ROOT = Path(__file__).resolve().parents[1]


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


def cpu_s(pid: int) -> float:
    """utime + stime of a live process (all its threads), seconds."""
    fields = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def tree_cpu_s(pid: int) -> float:
    """CPU seconds (user + system) of a live process, its descendants alive now and the
    children it has waited for, from /proc."""

    def stat(p: int) -> list[str]:
        return Path(f"/proc/{p}/stat").read_text().rpartition(")")[2].split()

    parents: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            with contextlib.suppress(OSError, IndexError):
                parents[int(entry.name)] = int(stat(int(entry.name))[1])
    tree, todo = [], [pid]
    while todo:
        p = todo.pop()
        tree.append(p)
        todo.extend(c for c, parent in parents.items() if parent == p)
    total = 0
    for p in tree:
        with contextlib.suppress(OSError, IndexError):
            f = stat(p)
            total += int(f[11]) + int(f[12]) + int(f[13]) + int(f[14])
    return total / CLK_TCK


def memory_mb(pid: int) -> tuple[float, float]:
    """(VmRSS, VmHWM: the peak resident size so far) of a live process, MB."""
    values = {"VmRSS:": float("nan"), "VmHWM:": float("nan")}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        key = line.split(":", 1)[0] + ":"
        if key in values:
            values[key] = int(line.split()[1]) / 1024
    return values["VmRSS:"], values["VmHWM:"]


class Procs:
    """The subprocesses of one part: every one still running is ended in ``close``."""

    def __init__(self) -> None:
        self.procs: list[subprocess.Popen[str]] = []
        self.closers: list[Callable[[], object]] = []

    def start(self, cmd: list[str], **kw: Any) -> subprocess.Popen[str]:
        proc = subprocess.Popen(cmd, cwd=ROOT, text=True, **kw)
        self.procs.append(proc)
        return proc

    def close(self) -> None:
        for close in self.closers:
            with contextlib.suppress(Exception):
                close()
        for proc in self.procs:
            end(proc)
            if proc.stdin is not None:
                with contextlib.suppress(OSError):
                    proc.stdin.close()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class RecorderExited(RuntimeError):
    """``acq record`` ended before it was stopped; ``summary``: its error and where."""

    def __init__(self, code: int, log_text: str) -> None:
        lines = [ln.rstrip() for ln in log_text.splitlines() if ln.strip()]
        error = next(
            (
                ln.strip()
                for ln in reversed(lines)
                if re.match(r"\w+(Error|Exception)\b", ln.strip())
            ),
            lines[-1] if lines else "",
        )
        where = [ln.strip() for ln in lines if ln.strip().startswith('File "')]
        self.code = code
        self.summary = error + (f" ({where[-1]})" if where else "")
        super().__init__(f"acq record exited early ({code}): {self.summary}")


@dataclass
class Run:
    """One ``acq record`` subprocess and what was measured of it."""

    proc: subprocess.Popen[str]
    out: Path
    log: Path
    t_start: float
    exit_code: int | None = None
    wall_s: float = 0.0
    rusage_cpu_s: float = 0.0
    samples: list[tuple[float, float, float]] = field(default_factory=list)  # (t, cpu, rss)
    peaks: list[float] = field(default_factory=list)  # VmHWM at each sample, MB

    def sample(self) -> tuple[float, float, float]:
        """(s since the start, CPU s, VmRSS MB) now, kept in ``samples``."""
        rss, hwm = memory_mb(self.proc.pid)
        s = (time.monotonic() - self.t_start, cpu_s(self.proc.pid), rss)
        self.samples.append(s)
        self.peaks.append(hwm)
        return s

    def sleep_until(self, t: float) -> None:
        """Sleep until ``t`` s after the start; fail at once if the recorder exits."""
        while (left := self.t_start + t - time.monotonic()) > 0:
            time.sleep(min(left, 0.5))
            if self.proc.poll() is not None:
                raise RecorderExited(self.proc.returncode, self.log.read_text(errors="replace"))

    def wait_for(self, *texts: str, timeout: float = 30.0) -> None:
        """Wait until the recorder's log holds every one of ``texts``."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            log = self.log.read_text(errors="replace")
            if all(t in log for t in texts):
                return
            if self.proc.poll() is not None:
                raise RecorderExited(self.proc.returncode, log)
            time.sleep(0.05)
        raise RuntimeError(f"acq record: no {texts!r} in its log within {timeout:g} s")

    def stop(self) -> None:
        """SIGTERM, then the exit status and rusage of the whole run (``os.wait4``)."""
        self.proc.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + 15.0
        while True:
            pid, status, ru = os.wait4(self.proc.pid, os.WNOHANG)
            if pid:
                break
            if time.monotonic() > deadline:
                self.proc.kill()
                pid, status, ru = os.wait4(self.proc.pid, 0)
                break
            time.sleep(0.02)
        self.wall_s = time.monotonic() - self.t_start
        self.exit_code = self.proc.returncode = os.waitstatus_to_exitcode(status)
        self.rusage_cpu_s = ru.ru_utime + ru.ru_stime

    def files(self) -> list[Path]:
        return sorted(self.out.glob("*.mcap"))

    def bytes_on_disk(self) -> int:
        return sum(p.stat().st_size for p in self.files())

    def warnings(self) -> list[str]:
        """The recorder's WARNING/ERROR lines, without their time stamps."""
        lines = self.log.read_text(errors="replace").splitlines()
        return [ln.split(" ", 2)[2] for ln in lines if " WARNING " in ln or " ERROR " in ln]


@contextlib.contextmanager
def workdir(prefix: str, keep: bool) -> Iterator[Path]:
    """A new temporary folder, removed at the end unless ``keep`` (then named on stderr)."""
    path = Path(tempfile.mkdtemp(prefix=prefix))
    try:
        yield path
    finally:
        if keep:
            print(f"# kept {path}", file=sys.stderr)
        else:
            shutil.rmtree(path, ignore_errors=True)
