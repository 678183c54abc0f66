"""A simulated Hokuyo scanner speaking SCIP 2.0 (URG-04LX, UTM-30LX) or 2.2 (UST-10LX).

It answers like the real devices: the command echoed, a checksummed status, data lines
with checksums, LF LF at the end; VV/PP/II in the devices' own format; scans of the
synthetic street (``StreetSource``) at the model's rate, time-stamped by the device's own
24-bit millisecond clock (``SimClock``). Serve it with ``acq.sim.transport.TcpDeviceServer`` or
``PtyDeviceServer``.

Differences between the models follow the real ones: ME/GE only where the model has
intensities, ND/NE/HD/HE only on multi-echo models (others answer status 0E), SS only
on serial models; SCIP 2.2 (UST) reports ``PROT:SCIP 2.2``, a 4-character II TIME and a
different II wording, and adds the UST's state commands (Hokuyo, "Communication Protocol
Specification for UST Series 10LX/20LX", C-42-04076, and the SCIP 2.2 detail it refers
to, C-42-03886; read as hokuyolx, written against a real UST-10LX, reads them):

- ``%ST`` sensor state, one data line: ``000`` standby, ``002`` time adjustment (TM),
  ``003`` single scan (laser on), ``004`` multi scan (streaming), ``005`` sleep;
  answered in any state, like ``VV`` and ``II``;
- ``%SL`` sleep (laser and measurement off until ``BM`` or a scan command);
- ``RT`` partial reset: ``RS`` but for the bit rate;
- ``RB`` reboot, sent twice within a second (``01``, then ``00``).

The SCIP 2.0 models answer these ``0E``, the status for an undefined command (Hokuyo,
"Communication Protocol Specification for SCIP2.0", C-42-03320B, section 9), as a
URG-04LX or UTM-30LX does.
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from acq.drivers.scip_codec import checksum, encode, encode_lines
from acq.sim.device_clock import SimClock
from acq.sim.scan_source import StreetSource
from acq.sim.scanner_models import ScannerModel

__all__ = ["ScipDevice", "SentScan"]

VENDOR = "Hokuyo Automatic Co.,Ltd."
SCAN_CMDS = {"MD", "MS", "ME", "ND", "NE", "GD", "GS", "GE", "HD", "HE"}
BITRATES = {19200, 38400, 57600, 115200, 250000, 500000, 750000}


@dataclass(frozen=True)
class SentScan:
    """What the device sent for one scan, for tests: raw mm codes and intensities per point."""

    command: str
    timestamp: int
    t0: float  # true time of step 0, s
    t_stamp: float  # true time the timestamp refers to (the step behind the sensor), s
    start: int
    end: int
    cluster: int
    ranges_mm: np.ndarray
    intensities: np.ndarray | None
    extra_mm: list[list[int]] = field(default_factory=list)  # further echoes per point
    telegram: bytes = b""
    t_sent: float = 0.0  # host monotonic s the telegram was made (then written at once), s


@dataclass
class _Stream:
    command: str
    start: int
    end: int
    cluster: int
    interval: int
    remaining: int  # 0: endless
    text: str
    k: int  # index of the next scan to send
    echo_cluster: int  # the cluster field as requested (00 and 01 both mean no grouping)


# SCIP 2.2 commands a UST answers in any state, the time adjustment state included
_ANY_STATE = {"%ST", "VV", "II"}


def _status(code: str) -> bytes:
    b = code.encode()
    return b + bytes([checksum(b)]) + b"\n"


class ScipDevice:
    """``SimDevice`` for a Hokuyo model (see module doc). ``now`` is time.monotonic() s."""

    _stream: _Stream | None
    _finite: bool

    def __init__(
        self,
        model: ScannerModel,
        source: StreetSource | None = None,
        clock: SimClock | None = None,
        *,
        bad_info_checksum: bool = False,
        seed: int = 0,
    ) -> None:
        if model.vendor != "hokuyo":
            raise ValueError(f"{model.name} is not a SCIP device")
        self.model = model
        self.source = source if source is not None else StreetSource(model, seed=seed)
        self.clock = (
            clock
            if clock is not None
            else SimClock(tick_hz=model.clock_hz, wrap_bits=model.clock_bits)
        )
        self.scip22 = model.protocol == "scip2.2"
        self.bad_info_checksum = bad_info_checksum
        self.dmin = round(model.range_min * 1000)
        self.dmax = round(model.range_max * 1000)
        self.period = model.scan_period
        self.step_dt = self.period / model.ares
        urg = "URG" in model.name.upper()
        # error codes sent for no echo / too close / other (URG-04LX vs UTM/UST tables)
        self.code_none, self.code_close, self.code_error = (1, 19, 10) if urg else (1, 2, 3)
        self.sent: deque[SentScan] = deque(maxlen=500)
        self.commands: list[str] = []
        self._corrupt = False
        self._power_on()

    # --- SimDevice -------------------------------------------------------------------

    def handle(self, data: bytes, now: float) -> bytes:
        self._inbuf += data
        out = bytearray()
        while True:
            cut = min(
                (i for i in (self._inbuf.find(b"\n"), self._inbuf.find(b"\r")) if i >= 0),
                default=-1,
            )
            if cut < 0:
                break
            line = bytes(self._inbuf[:cut])
            del self._inbuf[: cut + 1]
            if line:
                out += self._reply(line, now)
        if len(self._inbuf) > 4096:
            self._inbuf.clear()
        return bytes(out)

    def poll(self, now: float) -> bytes:
        s = self._stream
        if s is None:
            return b""
        out = bytearray()
        # far behind (the host was busy for over a second): skip ahead; a shorter delay
        # comes out as a burst, as a real device's buffered telegrams would
        if self._due(s.k, s) < now - 1.0:
            stride = s.interval + 1
            while self._due(s.k, s) < now - self.period:
                s.k += stride
        while self._stream is not None and self._due(s.k, s) <= now:
            if s.remaining:
                s.remaining -= 1
            echo = self._scan_echo(
                s.command, s.start, s.end, s.echo_cluster, s.interval, s.remaining
            )
            out += self._scan_telegram(echo, s.command, s.start, s.end, s.cluster, s.k, b"99")
            s.k += s.interval + 1
            if s.remaining == 0 and self._finite:
                self._stream = None
                self.laser = False
        return bytes(out)

    def next_due(self, now: float) -> float | None:
        s = self._stream
        return None if s is None else self._due(s.k, s)

    def on_disconnect(self) -> None:
        self._stream = None
        self._inbuf.clear()
        self.laser = False
        self.tm_mode = False
        self.sleeping = False

    def reboot(self, now: float) -> None:
        self.clock.reboot(now)
        self._power_on()

    def corrupt_next(self) -> None:
        self._corrupt = True

    # --- state ---------------------------------------------------------------------

    def _power_on(self) -> None:
        self._inbuf = bytearray()
        self.laser = False
        self.tm_mode = False
        self.sleeping = False
        self.high_sensitivity = False
        self.bitrate = 19200
        self._stream = None
        self._finite = False
        self._rb_at = -math.inf

    def _reset(self, now: float, *, keep_bitrate: bool) -> None:
        """RS (everything back to power-on) or RT (the same but the bit rate): standby,
        laser off, normal sensitivity, the internal timer back to 0 (SCIP 2.0 spec 8.5;
        the UST spec likewise). Commands already received stay queued."""
        inbuf, bitrate = self._inbuf, self.bitrate
        self._power_on()
        self._inbuf = inbuf
        if keep_bitrate:
            self.bitrate = bitrate
        if isinstance(self.clock, SimClock):  # not a replay's: that runs as recorded
            self.clock.epoch, self.clock.offset_ticks = now, 0.0

    def _scan_index_after(self, t: float) -> int:
        return math.ceil((t - self.clock.epoch) / self.period)

    def _t0(self, k: int) -> float:
        return self.clock.epoch + k * self.period

    def _due(self, k: int, s: _Stream) -> float:
        return self._t0(k) + (s.end + 1) * self.step_dt

    # --- replies -------------------------------------------------------------------

    def _finish(self, reply: bytes) -> bytes:
        """Apply a pending checksum corruption to the last checksummed line of ``reply``."""
        if not self._corrupt:
            return reply
        self._corrupt = False
        lines = reply[:-2].split(b"\n")
        i = len(lines) - 1
        if i < 1:
            return reply
        last = bytearray(lines[i])
        last[-1] = ((last[-1] - 0x30 + 1) % 64) + 0x30
        lines[i] = bytes(last)
        return b"\n".join(lines) + b"\n\n"

    def _simple(self, echo: bytes, status: str) -> bytes:
        return self._finish(echo + b"\n" + _status(status) + b"\n")

    def _info(self, echo: bytes, items: list[tuple[str, str]]) -> bytes:
        out = bytearray(echo + b"\n" + _status("00"))
        for key, value in items:
            body = f"{key}:{value}".encode()
            quirk = self.bad_info_checksum and key in ("FIRM", "DMAX")
            out += body + b";" + bytes([checksum(body + b";" if quirk else body)]) + b"\n"
        return self._finish(bytes(out) + b"\n")

    def _time_field(self, now: float) -> str:
        ticks = self.clock.ticks(now)
        if self.scip22:
            return encode([ticks], 4).decode()
        return f"{ticks:06X}"

    def _reply(self, line: bytes, now: float) -> bytes:
        self.commands.append(line.decode("ascii", "replace"))
        body, _, text = line.partition(b";")
        if len(text) > 16:
            return self._simple(line, "0G")
        try:
            cmd = body.decode("ascii")
        except UnicodeDecodeError:
            return self._simple(line, "0E")
        op, params = cmd[:2], cmd[2:]
        if cmd == "SCIP2.0":
            return self._simple(line, "0E")
        if self.tm_mode and op not in ("TM", "RS") and not (self.scip22 and cmd in _ANY_STATE):
            return self._simple(line, "0E")
        m = self.model
        if op == "VV" and not params:
            return self._info(
                line,
                [
                    ("VEND", VENDOR),
                    ("PROD", m.product),
                    ("FIRM", m.firmware),
                    ("PROT", "SCIP 2.2" if self.scip22 else "SCIP 2.0"),
                    ("SERI", m.serial),
                ],
            )
        if op == "PP" and not params:
            modl = m.name.upper() if self.scip22 else f"{m.name.upper()}({VENDOR})"
            return self._info(
                line,
                [
                    ("MODL", modl),
                    ("DMIN", str(self.dmin)),
                    ("DMAX", str(self.dmax)),
                    ("ARES", str(m.ares)),
                    ("AMIN", str(m.amin)),
                    ("AMAX", str(m.amax)),
                    ("AFRT", str(m.afrt)),
                    ("SCAN", str(m.rpm)),
                ],
            )
        if op == "II" and not params:
            return self._info(line, self._ii_items(now))
        if op == "BM" and not params:
            if self.laser:
                return self._simple(line, "02")
            self.laser = True
            self.sleeping = False
            return self._simple(line, "00")
        if op == "QT" and not params:
            self._stream = None
            self.laser = False
            return self._simple(line, "00")
        if op == "RS" and not params:
            self._reset(now, keep_bitrate=False)
            return self._simple(line, "00")
        if op == "TM":
            return self._tm(line, params, now)
        if op == "SS":
            return self._ss(line, params)
        if op == "HS" and params in ("0", "1"):
            if self.high_sensitivity == (params == "1"):
                return self._simple(line, "02")
            self.high_sensitivity = params == "1"
            return self._simple(line, "00")
        if op in SCAN_CMDS:
            return self._scan_command(line, op, params, now)
        if self.scip22 and op == "RB" and not params:
            if now - self._rb_at <= 1.0:
                self._rb_at = -math.inf
                reply = self._simple(line, "00")
                self.reboot(now)
                return reply
            self._rb_at = now
            return self._simple(line, "01")
        if self.scip22 and cmd == "%SL":
            self._stream = None
            self.laser = False
            self.sleeping = True
            return self._simple(line, "00")
        if self.scip22 and cmd == "%ST":
            state = self._state_code().encode()
            return self._finish(
                line + b"\n" + _status("00") + state + bytes([checksum(state)]) + b"\n\n"
            )
        if self.scip22 and op == "RT" and not params:
            self._reset(now, keep_bitrate=True)
            return self._simple(line, "00")
        return self._simple(line, "0E")

    def _state_code(self) -> str:
        """The ``%ST`` sensor state: 000 standby, 002 time adjustment, 003 single scan (laser
        on), 004 multi scan (streaming), 005 sleep."""
        if self.tm_mode:
            return "002"
        if self.sleeping:
            return "005"
        if self._stream is not None:
            return "004"
        return "003" if self.laser else "000"

    def _ii_items(self, now: float) -> list[tuple[str, str]]:
        m = self.model
        if self.scip22:
            return [
                ("MODL", m.name.upper()),
                ("LASR", "ON" if self.laser else "OFF"),
                ("SCSP", str(m.rpm)),
                ("MESM", "001 Measuring" if self._stream else "000 Idle"),
                ("SBPS", "Ethernet 100 [Mbps]"),
                ("TIME", self._time_field(now)),
                ("STAT", "Stable 000 no error."),
            ]
        return [
            ("MODL", f"{m.name.upper()}({VENDOR})"),
            ("LASR", "ON" if self.laser else "OFF"),
            ("SCSP", f"Initial({m.rpm}[rpm])<-Default setting by user"),
            ("MESM", "High Sensitivity Mode" if self.high_sensitivity else "CLASSIC"),
            ("SBPS", "USB Full Speed"),
            ("TIME", self._time_field(now)),
            ("STAT", "Sensor works well."),
        ]

    def _tm(self, line: bytes, params: str, now: float) -> bytes:
        if params == "0":
            if self.tm_mode:
                return self._simple(line, "02")
            self.tm_mode = True
            self._stream = None
            self.laser = False
            return self._simple(line, "00")
        if params == "2":
            if not self.tm_mode:
                return self._simple(line, "03")
            self.tm_mode = False
            return self._simple(line, "00")
        if params == "1":
            if not self.tm_mode:
                return self._simple(line, "04")
            ts = encode([self.clock.ticks(now)], 4)
            return self._finish(line + b"\n" + _status("00") + ts + bytes([checksum(ts)]) + b"\n\n")
        return self._simple(line, "01")

    def _ss(self, line: bytes, params: str) -> bytes:
        if not self.model.serial_port:
            return self._simple(line, "0F")
        if len(params) != 6 or not params.isdigit():
            return self._simple(line, "01")
        rate = int(params)
        if rate not in BITRATES:
            return self._simple(line, "02")
        if rate == self.bitrate:
            return self._simple(line, "03")
        self.bitrate = rate
        return self._simple(line, "00")

    def _scan_command(self, line: bytes, op: str, params: str, now: float) -> bytes:
        m = self.model
        if (op[1] == "E" and not m.intensity) or (op[0] in "HN" and not m.multi_echo):
            return self._simple(line, "0E")
        continuous = op[0] in "MN"
        if len(params) != (13 if continuous else 10):
            return self._simple(line, "0C")
        fields = [params[0:4], params[4:8], params[8:10]]
        if continuous:
            fields += [params[10:11], params[11:13]]
        for i, f in enumerate(fields):
            if not f.isdigit():
                return self._simple(line, ("01", "02", "03", "06", "07")[i])
        start, end, echo_cluster = int(fields[0]), int(fields[1]), int(fields[2])
        if end > m.amax or start < m.amin:
            return self._simple(line, "04")
        if end < start:
            return self._simple(line, "05")
        cluster = max(echo_cluster, 1)
        if not continuous:
            if not self.laser:
                return self._simple(line, "10")
            k = self._scan_index_after(now) - 1
            while self._t0(k) + (end + 1) * self.step_dt > now:
                k -= 1
            return self._scan_telegram(line, op, start, end, cluster, k, b"00")
        interval, count = int(fields[3]), int(fields[4])
        text = line.partition(b";")[2].decode("ascii", "replace")
        self._stream = _Stream(
            op,
            start,
            end,
            cluster,
            interval,
            count,
            text,
            self._scan_index_after(now),
            echo_cluster,
        )
        self._finite = count > 0
        self.laser = True
        self.sleeping = False
        return self._simple(line, "00")

    # --- scans ---------------------------------------------------------------------

    def _scan_echo(
        self, op: str, start: int, end: int, cluster: int, interval: int, remaining: int
    ) -> bytes:
        s = f"{op}{start:04d}{end:04d}{cluster:02d}{interval}{remaining:02d}"
        text = self._stream.text if self._stream is not None else ""
        return (s + (";" + text if text else "")).encode()

    def _codes(self, ranges: np.ndarray) -> np.ndarray:
        """Metres (REP-117) -> mm values with the model's error codes."""
        with np.errstate(invalid="ignore"):
            mm = np.where(np.isfinite(ranges), np.round(ranges * 1000.0), 0).astype(np.int64)
        codes = mm.copy()
        codes[(mm < self.dmin) & np.isfinite(ranges)] = self.code_close
        codes[mm > self.dmax] = self.code_none
        codes[np.isposinf(ranges)] = self.code_none
        codes[np.isneginf(ranges)] = self.code_close
        codes[np.isnan(ranges)] = self.code_error
        return codes

    def _scan_telegram(
        self, echo: bytes, op: str, start: int, end: int, cluster: int, k: int, status: bytes
    ) -> bytes:
        m = self.model
        t0 = self._t0(k)
        # the stamp refers to the step straight behind the sensor, as on the real devices
        t_stamp = t0 + (m.afrt - m.ares // 2) * self.step_dt
        ts = self.clock.ticks(t_stamp)
        ranges, intens = self.source.scan(t0 + m.amin * self.step_dt)
        sel = slice(start - m.amin, end - m.amin + 1)
        codes = self._codes(np.asarray(ranges, dtype=np.float64)[sel])
        inten = np.clip(np.round(np.asarray(intens, dtype=np.float64)[sel]), 0, (1 << 18) - 1)
        inten = inten.astype(np.int64)
        width = 2 if op[1] == "S" else 3
        if width == 2:
            codes = np.where(codes > 4095, 16, codes)
        if cluster > 1:  # per cluster: the smallest valid value, else the first code
            n = -(-codes.size // cluster)
            pad = n * cluster - codes.size
            c2 = np.concatenate([codes, np.full(pad, codes[-1])]).reshape(n, cluster)
            i2 = np.concatenate([inten, np.full(pad, inten[-1])]).reshape(n, cluster)
            masked = np.where(c2 >= self.dmin, c2, np.iinfo(np.int64).max)
            pick = np.where((c2 >= self.dmin).any(axis=1), masked.argmin(axis=1), 0)
            codes = c2[np.arange(n), pick]
            inten = i2[np.arange(n), pick]
        with_int = op[1] == "E"
        extra: list[list[int]] = []
        if op[0] in "HN":
            rec = 6 if with_int else 3
            base = encode(np.stack([codes, inten], axis=1).ravel() if with_int else codes, 3)
            idx = np.arange(codes.size)
            has1 = (codes >= self.dmin) & (idx % 9 == 0)
            has2 = has1 & (idx % 27 == 0)
            e1 = np.minimum(codes + 300 + 100 * (idx % 3), self.dmax)
            e2 = np.minimum(codes + 1500, self.dmax)
            enc1 = encode(np.stack([e1, inten // 2], axis=1).ravel() if with_int else e1, 3)
            enc2 = encode(np.stack([e2, inten // 3], axis=1).ravel() if with_int else e2, 3)
            pieces: list[bytes] = []
            for i in range(codes.size):
                a = i * rec
                pieces.append(base[a : a + rec])
                more: list[int] = []
                if has1[i]:
                    pieces.append(b"&" + enc1[a : a + rec])
                    more.append(int(e1[i]))
                    if has2[i]:
                        pieces.append(b"&" + enc2[a : a + rec])
                        more.append(int(e2[i]))
                extra.append(more)
            payload = b"".join(pieces)
        elif with_int:
            payload = encode(np.stack([codes, inten], axis=1).ravel(), 3)
        else:
            payload = encode(codes, width)
        tsb = encode([ts], 4)
        telegram = self._finish(
            echo
            + b"\n"
            + status
            + bytes([checksum(status)])
            + b"\n"
            + tsb
            + bytes([checksum(tsb)])
            + b"\n"
            + encode_lines(payload)
            + b"\n"
        )
        self.sent.append(
            SentScan(
                op,
                ts,
                t0,
                t_stamp,
                start,
                end,
                cluster,
                codes,
                inten if with_int else None,
                extra,
                telegram,
                time.monotonic(),
            )
        )
        return telegram
