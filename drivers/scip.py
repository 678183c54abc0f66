"""Hokuyo SCIP 2.0 / 2.2 driver (URG-04LX, UTM-30LX, UST-10LX...) over any pyserial URL.

``/dev/ttyACM0``, ``/dev/serial/by-id/...`` and ``socket://192.168.0.10:10940`` all go
through :func:`serial.serial_for_url`. ``connect()`` stops any running stream (QT),
identifies the device (VV, PP, II) and takes the geometry from PP; ``start()`` requests an
endless MD/ME/ND/NE stream; ``read_scan()`` returns one :class:`acq.records.Scan` per
telegram. The wire format lives in :mod:`acq.drivers.scip_codec`; this module only does I/O.
"""

from __future__ import annotations

import os
import select
import statistics
import time
from dataclasses import dataclass

import serial

from acq.drivers.scanner import (
    ConnectionLost,
    ProtocolError,
    Scanner,
    ScanTimeout,
)
from acq.drivers.scip_codec import (
    Reply,
    ScanEcho,
    ScipParams,
    checksum,
    decode_int,
    error_table_for,
    parse_info,
    parse_reply,
    parse_scan,
    parse_time_field,
    raise_for_status,
)
from acq.records import DeviceInfo, Scan

__all__ = ["LatencyEstimate", "ScipScanner", "parse_scan"]

_POLL_S = 0.02  # pyserial read timeout; the driver's own deadline is ``timeout``
_MAX_BUFFER = 1 << 20
_BAUDRATES = (19200, 38400, 57600, 115200, 250000, 500000, 750000)


@dataclass(frozen=True)
class LatencyEstimate:
    """TM round trips, seconds. ``one_way`` = min RTT / 2 bounds the constant latency.

    ``spread`` = median - min RTT (jitter); ``offset_s`` = device time minus host time at
    the min-RTT sample (device ms counter, not unwrapped), for information. ``samples``
    holds every round trip as (host ns sent, device tick, host ns received), for
    :func:`acq.time.clocksync.latency_bounds`.
    """

    n: int
    rtt_min: float
    rtt_median: float
    rtt_max: float
    one_way: float
    spread: float
    offset_s: float
    samples: tuple[tuple[int, int, int], ...] = ()


class ScipScanner(Scanner):
    """One Hokuyo scanner speaking SCIP 2.0 (or 2.2) on a pyserial URL.

    Options: ``intensity`` (ME/NE), ``multi_echo`` (ND/NE), ``angle_min``/``angle_max``
    (rad, REP-103; cropped to whole steps), ``cluster`` (steps merged per point),
    ``two_char`` (MS: 2-character ranges, < 4.1 m), ``baudrate`` (RS-232 devices: switched
    with SS after identification; the port opens at ``initial_baudrate``),
    ``accept_bad_info_checksum`` (tolerate the URG-04LX firmware that sends wrong checksums
    on VV/PP/II lines), ``timeout`` (s, per read_scan and per command).
    """

    driver = "hokuyo"
    wire = "SCIP"
    url_kind = "serial"
    latency_probe = "SCIP TM round trips"  # measure_latency

    def __init__(
        self,
        url: str,
        *,
        name: str = "laser",
        timeout: float = 1.0,
        baudrate: int | None = None,
        initial_baudrate: int = 19200,
        intensity: bool = False,
        multi_echo: bool = False,
        angle_min: float | None = None,
        angle_max: float | None = None,
        cluster: int = 1,
        two_char: bool = False,
        accept_bad_info_checksum: bool = False,
    ) -> None:
        super().__init__(url, name=name, timeout=timeout)
        if not 1 <= cluster <= 99:
            raise ValueError(f"cluster must be 1..99, got {cluster}")
        if two_char and (intensity or multi_echo):
            raise ValueError("two_char (MS) has no intensity or multi-echo variant")
        if baudrate is not None and baudrate not in _BAUDRATES:
            raise ValueError(f"baudrate must be one of {_BAUDRATES}")
        self.baudrate = baudrate
        self.initial_baudrate = initial_baudrate
        self.intensity = intensity
        self.multi_echo = multi_echo
        self.angle_range = (angle_min, angle_max)
        self.cluster = cluster
        self.two_char = two_char
        self.accept_bad_info_checksum = accept_bad_info_checksum
        self.params: ScipParams | None = None
        self.protocol = ""
        self.steps: tuple[int, int] = (0, 0)
        self.bad_info_checksums = 0
        self._ser: serial.SerialBase | None = None
        self._sock_fd: int | None = None
        self._buf = bytearray()
        self._marks: list[tuple[int, int]] = []  # (end offset in _buf, monotonic ns)
        self._stream: ScanEcho | None = None
        self._prefix = b""
        self._errors: dict[int, float] = {}
        self._sequence = 0

    # --- life cycle ------------------------------------------------------------------

    @property
    def command(self) -> str:
        """The continuous scan command the options select (MD, MS, ME, ND, NE)."""
        if self.multi_echo:
            return "NE" if self.intensity else "ND"
        if self.intensity:
            return "ME"
        return "MS" if self.two_char else "MD"

    def connect(self) -> DeviceInfo:
        self.close()
        try:
            self._ser = serial.serial_for_url(
                self.url,
                baudrate=self.initial_baudrate,
                timeout=_POLL_S,
                write_timeout=max(self.timeout, 0.1),
            )
        except (serial.SerialException, OSError, ValueError) as e:
            raise ConnectionLost(f"{self.url}: cannot open: {e}") from e
        # A socket, or a POSIX serial port: read its descriptor directly (see _read_chunk).
        fd = getattr(self._ser, "fd", None) if "://" not in self.url else None
        self._sock_fd = self._ser.fileno() if self.url.startswith("socket://") else fd
        self._buf.clear()
        self._marks.clear()
        self._stop_any_stream()
        vv_reply = self._command("VV", info=True)
        vv = parse_info(vv_reply)
        pp = parse_info(self._command("PP", info=True))
        ii = parse_info(self._command("II", info=True))
        self.params = ScipParams.from_info(pp)
        self.protocol = vv.get("PROT", "")
        self._errors = error_table_for(pp.get("MODL", "") or vv.get("PROD", ""))
        start, end = self.params.steps_for(*self.angle_range)
        self.steps = (start, end)
        self.geometry = self.params.geometry(start, end, self.cluster)
        extra = {f"PP.{k}": v for k, v in pp.items()}
        extra.update({f"II.{k}": v for k, v in ii.items()})
        extra.update({f"VV.{k}": v for k, v in vv.items()})
        if "TIME" in ii:
            try:
                extra["device_ticks"] = str(parse_time_field(ii["TIME"]))
            except ProtocolError:
                pass
        self.info = DeviceInfo(
            name=self.name,
            driver=self.driver,
            vendor=vv.get("VEND", ""),
            model=vv.get("PROD", ""),
            serial=vv.get("SERI", ""),
            firmware=vv.get("FIRM", ""),
            extra=extra,
        )
        if self.baudrate is not None and self._is_serial():
            self._change_baudrate(self.baudrate)
        return self.info

    def start(self) -> None:
        if self.params is None:
            raise RuntimeError("connect() first")
        start, end = self.steps
        echo = ScanEcho(self.command, start, end, self.cluster, 0, 0)
        cmd = echo.prefix().decode() + "00"  # 00 scans: stream until QT
        self._command(cmd)
        self._stream = echo
        self._prefix = echo.prefix()
        self._sequence = 0

    def read_scan(self) -> Scan:
        if self._stream is None or self.params is None:
            raise RuntimeError("start() first")
        deadline = time.monotonic() + self.timeout
        while True:
            block, recv_ns = self._read_block(deadline)
            at = _find_echo(block, self._prefix, tail=2)
            if at < 0:
                continue  # garbage, an acknowledgement, a stale reply: skip to the next echo
            telegram = block[at:]
            if telegram[len(self._prefix) + 2 : len(self._prefix) + 7] == b"\n00P\n":
                continue  # the stream's "00" acknowledgement
            self._sequence += 1
            return parse_scan(
                telegram,
                self.params,
                recv_ns=recv_ns,
                sequence=self._sequence,
                errors=self._errors,
            )

    def stop(self) -> None:
        if self._ser is None:
            return
        self._stream = None
        self._command("QT", ok=("00", "01", "02"))

    def close(self) -> None:
        ser, self._ser = self._ser, None
        self._stream = None
        self._sock_fd = None
        if ser is None:
            return
        try:
            ser.write(b"QT\n")
            ser.flush()
        except (serial.SerialException, OSError):
            pass
        try:
            ser.close()
        except (serial.SerialException, OSError):
            pass

    # --- other commands ----------------------------------------------------------------

    def single_scan(self) -> Scan:
        """One GD/GS/GE/HD/HE scan (laser switched on with BM first)."""
        if self.params is None:
            raise RuntimeError("connect() first")
        if self._stream is not None:
            raise RuntimeError("stop() the stream first")
        self._command("BM", ok=("00", "02"))
        start, end = self.steps
        cmd = "G" + self.command[1] if self.command[0] == "M" else "H" + self.command[1]
        text = f"{cmd}{start:04d}{end:04d}{self.cluster:02d}"
        reply, recv_ns = self._exchange(text)
        self._sequence += 1
        return parse_scan(
            reply, self.params, recv_ns=recv_ns, sequence=self._sequence, errors=self._errors
        )

    def reset(self) -> None:
        """RS: stop measuring, laser off, settings back to defaults."""
        self._stream = None
        self._command("RS")

    def device_time(self) -> int:
        """II TIME: the device's ms counter now (needs no TM mode)."""
        ii = parse_info(self._command("II", info=True))
        if "TIME" not in ii:
            raise ProtocolError("II reply has no TIME field")
        return parse_time_field(ii["TIME"])

    def measure_latency(self, n: int = 10) -> LatencyEstimate:
        """Enter TM mode, time ``n`` TM1 round trips, leave it; bounds the one-way latency."""
        if n < 1:
            raise ValueError("n must be >= 1")
        if self._stream is not None:
            self.stop()
        self._command("TM0", ok=("00", "02"))
        rtts: list[float] = []
        samples: list[tuple[int, int, int]] = []
        best = (float("inf"), 0.0)
        try:
            for _ in range(n):
                t0 = time.monotonic_ns()
                block, t1 = self._exchange("TM1")
                reply = parse_reply(block)
                raise_for_status("TM1", reply.status)
                if len(reply.lines) != 1 or len(reply.lines[0]) != 4:
                    raise ProtocolError(f"TM1 reply has no 4-char time: {block!r}")
                tick = decode_int(reply.lines[0])
                rtt = (t1 - t0) * 1e-9
                rtts.append(rtt)
                samples.append((t0, tick, t1))
                if rtt < best[0]:
                    best = (rtt, tick * 1e-3 - (t0 + t1) * 0.5e-9)
        finally:
            self._command("TM2", ok=("00", "03"))
        rmin = min(rtts)
        med = statistics.median(rtts)
        return LatencyEstimate(
            n=n,
            rtt_min=rmin,
            rtt_median=med,
            rtt_max=max(rtts),
            one_way=rmin / 2,
            spread=med - rmin,
            offset_s=best[1],
            samples=tuple(samples),
        )

    def sleep(self) -> None:
        """SCIP 2.2 ``%SL``: stop the motor and laser until the next measurement command."""
        self._stream = None
        self._command("QT", ok=("00", "01", "02"))
        self._command("%SL")

    # --- I/O helpers -----------------------------------------------------------------

    def _is_serial(self) -> bool:
        return "://" not in self.url

    def _write(self, data: bytes) -> None:
        if self._ser is None:
            raise ConnectionLost("not connected")
        try:
            self._ser.write(data)
        except (serial.SerialException, OSError) as e:
            raise ConnectionLost(f"{self.url}: write failed: {e}") from e

    def _read_block(self, deadline: float) -> tuple[bytes, int]:
        """Bytes up to and including the next LF LF, and the ns its last byte arrived.
        Past ``deadline``, what has already arrived is still read once before ScanTimeout:
        a host that held this thread up (a loaded machine) is not a device gone quiet."""
        late = False
        while True:
            end = self._buf.find(b"\n\n")
            if end >= 0:
                n = end + 2
                block = bytes(self._buf[:n])
                del self._buf[:n]
                recv_ns = next((t for off, t in self._marks if off >= n), time.monotonic_ns())
                self._marks = [(off - n, t) for off, t in self._marks if off > n]
                return block, recv_ns
            if late:
                raise ScanTimeout(f"{self.url}: no complete telegram within {self.timeout} s")
            late = time.monotonic() >= deadline
            if self._ser is None:
                raise ConnectionLost("not connected")
            try:
                chunk = self._read_chunk(deadline)
            except (serial.SerialException, OSError) as e:
                raise ConnectionLost(f"{self.url}: {e}") from e
            if chunk:
                self._buf += chunk
                self._marks.append((len(self._buf), time.monotonic_ns()))
                if len(self._buf) > _MAX_BUFFER:  # no framing in a megabyte: drop it
                    del self._buf[: -(1 << 16)]
                    self._marks = [(len(self._buf), self._marks[-1][1])]

    def _read_chunk(self, deadline: float) -> bytes:
        """What has arrived (waits at most until ``deadline``, in short polls)."""
        assert self._ser is not None
        if self._sock_fd is None:  # other pyserial URL handlers: in_waiting is the byte count
            # types-pyserial types serial_for_url as SerialBase; every handler it returns has
            # in_waiting
            waiting = self._ser.in_waiting  # type: ignore[attr-defined]
            return bytes(self._ser.read(max(1, waiting)))
        # pyserial's socket read() goes byte by byte or waits for its whole timeout, and
        # its serial read() loops and throws away what it already read when the device
        # vanishes mid-telegram (an unplugged cable): read the descriptor directly, so
        # no byte that arrived is lost and the receive time is that of its arrival.
        wait = min(_POLL_S, max(0.0, deadline - time.monotonic()))
        ready, _, _ = select.select([self._sock_fd], [], [], wait)
        if not ready:
            return b""
        try:
            chunk = os.read(self._sock_fd, 1 << 16)
        except BlockingIOError:
            return b""
        if not chunk:
            raise ConnectionLost(f"{self.url}: connection closed by the device")
        return chunk

    def _exchange(self, cmd: str) -> tuple[bytes, int]:
        """Send ``cmd`` and return its reply block (other blocks skipped) and receive ns."""
        want = cmd.encode("ascii")
        self._write(want + b"\n")
        deadline = time.monotonic() + self.timeout
        while True:
            try:
                block, recv_ns = self._read_block(deadline)
            except ScanTimeout:
                msg = f"{self.url}: no reply to {cmd!r} within {self.timeout} s"
                raise ScanTimeout(msg) from None
            at = _find_echo(block, want)
            if at >= 0:
                return block[at:], recv_ns

    def _command(self, cmd: str, ok: tuple[str, ...] = ("00",), info: bool = False) -> Reply:
        block, _ = self._exchange(cmd)
        lenient = info and self.accept_bad_info_checksum
        reply = self._lenient(block) if lenient else parse_reply(block, info=info)
        raise_for_status(cmd, reply.status, ok)
        return reply

    def _lenient(self, block: bytes) -> Reply:
        try:
            return parse_reply(block, info=True)
        except ProtocolError:
            self.bad_info_checksums += 1
            return parse_reply(block, info=True, lenient_info=True)

    def _stop_any_stream(self) -> None:
        """QT whatever the device is doing; leave TM mode; switch SCIP 1.1 to 2.0."""
        self._write(b"QT\n")
        deadline = time.monotonic() + max(self.timeout, 0.2)
        while True:
            try:
                block, _ = self._read_block(deadline)
            except ScanTimeout:
                raise ScanTimeout(f"{self.url}: no reply to QT: is this a SCIP device?") from None
            at = block.find(b"QT\n")
            if at < 0:
                continue  # scans of a running stream
            lines = block[at:].split(b"\n")
            status = lines[1] if len(lines) > 1 else b""
            if status == b"0Ee":  # in TM mode: nothing else is accepted
                self._command("TM2", ok=("00", "03"))
            elif len(status) == 1:  # SCIP 1.1 answers with one character
                self._command("SCIP2.0", ok=("00", "0E"))
            return

    def _change_baudrate(self, rate: int) -> None:
        assert self._ser is not None
        reply = self._command(f"SS{rate:06d}", ok=("00", "03", "04"))
        if reply.status == "00":
            time.sleep(0.05)
            try:
                self._ser.baudrate = rate
            except (serial.SerialException, OSError, ValueError) as e:
                raise ConnectionLost(f"{self.url}: cannot switch to {rate} Bd: {e}") from e


def _find_echo(block: bytes, echo: bytes, tail: int = 0) -> int:
    """Offset of ``echo`` (+ ``tail`` more chars) followed by a valid status line, or -1.

    Bytes before it are garbage (line noise, a half telegram); a false match inside data
    would need a checksummed status line right after it.
    """
    at = block.find(echo)
    while at >= 0:
        lf = at + len(echo) + tail
        st = block[lf + 1 : lf + 4]
        if (
            block[lf : lf + 1] == b"\n"
            and len(st) == 3
            and st[2] == checksum(st[:2])
            and block[lf + 4 : lf + 5] == b"\n"
        ):
            return at
        at = block.find(echo, at + 1)
    return -1
