"""A tiny line-protocol simulated device, to test transports and reconnection alone."""

from __future__ import annotations


class LineDevice:
    """Answers ``ping`` with ``pong``; after ``start`` streams ``tick N`` every 20 ms."""

    period = 0.02

    def __init__(self) -> None:
        self.streaming = False
        self.n = 0
        self.due = 0.0
        self.reboots = 0
        self.corrupt = False
        self.buf = b""

    def handle(self, data: bytes, now: float) -> bytes:
        self.buf += data
        out = b""
        while b"\n" in self.buf:
            line, self.buf = self.buf.split(b"\n", 1)
            if line == b"ping":
                out += b"pong\n"
            elif line == b"start":
                self.streaming, self.due = True, now
        return out

    def poll(self, now: float) -> bytes:
        out = b""
        while self.streaming and now >= self.due:
            self.n += 1
            self.due += self.period
            out += b"tick %d%s\n" % (self.n, b"!" if self.corrupt else b"")
            self.corrupt = False
        return out

    def next_due(self, now: float) -> float | None:
        return self.due if self.streaming else None

    def on_disconnect(self) -> None:
        self.streaming, self.buf = False, b""

    def reboot(self, now: float) -> None:
        self.reboots += 1
        self.n = 0

    def corrupt_next(self) -> None:
        self.corrupt = True
