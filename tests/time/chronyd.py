"""A real ``chronyd`` for tests, that never touches the host clock (``-x``): its own
configuration, pid file and command socket in a private folder, and one reference
clock (``refclock SOCK``) the test feeds with chrony's ``sock_sample`` structs saying
the reference is ``offset_s`` ahead of the host clock. Skips when chrony is not
installed (``make test`` installs Debian's ``chrony``)."""

from __future__ import annotations

import os
import shutil
import socket
import struct
import subprocess
import threading
import time
from pathlib import Path

import pytest

from acq.time.chrony import ChronyTracking, read_chrony_tracking

SOCK_MAGIC = 0x534F434B  # "SOCK": refclock_sock.c's struct sock_sample
SYNC_WITHIN_S = 5.0

CONFIG = """\
refclock SOCK {refclock} refid TEST poll -3 dpoll -5 filter 2 precision 1e-6
makestep 1e-6 -1
port 0
cmdport 0
bindcmdaddress {command}
pidfile {pid}
"""


def sock_sample(offset_s: float, now_s: float) -> bytes:
    """A ``struct sock_sample`` (LP64): the host time ``now_s`` of a sample whose
    reference time is ``offset_s`` later; no pulse, no leap."""
    seconds = int(now_s)
    return struct.pack(
        "qqdiiii", seconds, int((now_s - seconds) * 1e6), offset_s, 0, 0, 0, SOCK_MAGIC
    )


class Chronyd:
    """``chronyd -x`` following a reference ``offset_s`` ahead of the host clock, in
    ``folder`` (made private: chronyd wants its socket's folder closed to others)."""

    def __init__(self, folder: Path, offset_s: float) -> None:
        binary = shutil.which("chronyd") or (
            "/usr/sbin/chronyd" if os.path.exists("/usr/sbin/chronyd") else None
        )
        if binary is None or shutil.which("chronyc") is None:
            pytest.skip("chrony is not installed (Debian: apt-get install chrony)")
        folder.mkdir(mode=0o700, parents=True, exist_ok=True)
        folder.chmod(0o700)
        self.folder = folder
        self.offset_s = offset_s
        self.command = str(folder / "chronyd.sock")
        self.refclock = str(folder / "refclock.sock")
        conf = folder / "chrony.conf"
        conf.write_text(
            CONFIG.format(refclock=self.refclock, command=self.command, pid=folder / "chronyd.pid")
        )
        user = ["-u", "root"] if os.geteuid() == 0 else ["-U"]
        self.log = (folder / "chronyd.log").open("wb")
        self.proc = subprocess.Popen(
            [binary, "-x", "-d", *user, "-f", str(conf)], stdout=self.log, stderr=self.log
        )
        self._stop = threading.Event()
        self._feeder = threading.Thread(target=self._feed, daemon=True)
        self._feeder.start()

    def _feed(self) -> None:
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as s:
            while not self._stop.wait(0.03):
                try:
                    s.sendto(sock_sample(self.offset_s, time.time()), self.refclock)
                except OSError:
                    pass  # chronyd has not opened its socket yet

    def synchronised(self, within_s: float = SYNC_WITHIN_S) -> ChronyTracking:
        """chrony's tracking once it follows the test's reference; fails after
        ``within_s`` (with chronyd's log)."""
        deadline = time.monotonic() + within_s
        last: object = None
        while time.monotonic() < deadline:
            last = read_chrony_tracking(self.command)
            if isinstance(last, ChronyTracking) and last.synchronised:
                return last
            if self.proc.poll() is not None:
                break
            time.sleep(0.1)
        self.log.flush()
        log = (self.folder / "chronyd.log").read_text(errors="replace")
        pytest.fail(f"chronyd not synchronised within {within_s} s: {last}\n{log}")

    def close(self) -> None:
        self._stop.set()
        self._feeder.join(timeout=1.0)
        self.proc.kill()
        self.proc.wait(timeout=5.0)
        self.log.close()
