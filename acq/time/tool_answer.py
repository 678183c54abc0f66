"""A clock tool's answer (``chronyc``, ``pmc``), bounded in time and in size: the
recorder asks every second, so a tool that hangs or prints without end is a source
that is absent, never a stalled or swollen recorder."""

from __future__ import annotations

import os
import selectors
import subprocess
import time
from dataclasses import dataclass

from acq.time.absent import Absent

__all__ = ["ANSWER_MAX_BYTES", "ToolAnswer", "ask_tool"]

ANSWER_MAX_BYTES = 65536  # a tracking line is ~150 bytes, pmc's TIME_STATUS_NP ~1 kB


@dataclass(frozen=True)
class ToolAnswer:
    """What a tool printed (decoded, undecodable bytes replaced) and its exit status."""

    returncode: int
    stdout: str
    stderr: str


def ask_tool(
    command: list[str], name: str, timeout_s: float, max_bytes: int = ANSWER_MAX_BYTES
) -> ToolAnswer | Absent:
    """Run ``command`` (``name`` in the reasons) and read its output; :class:`Absent`
    when it cannot run, does not end within ``timeout_s`` (s) or prints more than
    ``max_bytes`` on stdout or stderr (it is killed then)."""
    try:
        proc = subprocess.Popen(
            command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE
        )
    except OSError as e:
        return Absent(f"{name} cannot run: {e.strerror or e}")
    assert proc.stdout is not None and proc.stderr is not None
    got = {proc.stdout.fileno(): bytearray(), proc.stderr.fileno(): bytearray()}
    deadline = time.monotonic() + timeout_s
    late = Absent(f"{name} gave no answer within {timeout_s:g} s")
    try:
        with selectors.DefaultSelector() as selector:
            for fd in got:
                selector.register(fd, selectors.EVENT_READ)
            while selector.get_map():
                left = deadline - time.monotonic()
                if left <= 0:
                    return late
                for key, _ in selector.select(left):
                    chunk = os.read(key.fd, 65536)
                    if not chunk:
                        selector.unregister(key.fd)
                        continue
                    got[key.fd] += chunk
                    if len(got[key.fd]) > max_bytes:
                        return Absent(f"{name} printed more than {max_bytes} bytes, not an answer")
        try:
            code = proc.wait(max(deadline - time.monotonic(), 0.0))
        except subprocess.TimeoutExpired:
            return late
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()
    out, err = (bytes(b).decode(errors="replace") for b in got.values())
    return ToolAnswer(code, out, err)
