"""Simulated devices that serve a recorded log instead of the synthetic street.

The recorded bytes go back out exactly as they came in: each scanner telegram as the
driver received it (``acq.RawTelegram.data``), each JPEG as the camera sent it, at the
times they were received (MCAP ``log_time``), shifted to now and divided by the speed.
A recorder that records the replay therefore gets the same device ticks, ranges and
JPEG bytes; only the receive times are new.

- :class:`ReplayClock` (the session's time axis) and :class:`ReplayStream` (one device's
  records on it) are in :mod:`acq.sim.replay_stream`.
- :class:`ScipReplayDevice` and :class:`ColaReplayDevice` are ``SimDevice``s (serve them
  with :class:`acq.sim.transport.TcpDeviceServer` or ``PtyDeviceServer``): they answer the
  start-up like the simulated devices (identity as recorded), and once the client starts
  the recorded measurement they stream the recorded telegrams. A client asking for a
  different measurement (another scan command or steps, other CoLa angles or channels) is
  refused (SCIP status ``0E``, CoLa ``sFA``) and ``report`` is called with why: a replay
  serves only what was recorded.
- :class:`ReplayMjpegServer` serves a camera's recorded JPEGs as MJPEG over HTTP.

When the log ends the devices go silent: connections stay open, nothing more is sent
(a reading client times out, as from a stalled device), until the server is closed.

Times are the host's ``time.monotonic()`` seconds; log times are the recording host's
monotonic nanoseconds.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from acq.drivers.cola_codec import STX4, Telegram, unframe
from acq.drivers.cola_scandata import ScanData, encode_scandata, parse_scandata
from acq.drivers.scanner import ProtocolError
from acq.drivers.scip_codec import (
    SCAN_COMMANDS,
    checksum,
    decode_int,
    encode_lines,
    parse_scan_echo,
)
from acq.sim.camera_device import SimFrame
from acq.sim.cola_device import ColaDevice, ScanShape
from acq.sim.device_clock import SimClock
from acq.sim.mjpeg_server import MjpegServer
from acq.sim.replay_stream import ReplayClock, ReplayStream
from acq.sim.scanner_models import MODELS, ScannerModel
from acq.sim.scip_device import ScipDevice

__all__ = [
    "ColaReplayDevice",
    "ReplayClock",
    "ReplayMjpegServer",
    "ReplayStream",
    "ScipReplayDevice",
    "cola_model",
    "scip_model",
]

Report = Callable[[str], None]


def _ignore(_msg: str) -> None:
    pass


class _NoSource:
    """Stands in for the street: a replay device renders nothing."""

    def scan(self, t0: float) -> Any:
        raise RuntimeError("a replay device has no street to scan")


# --- SCIP -----------------------------------------------------------------------------------


def scip_model(info: dict[str, Any], params: dict[str, Any]) -> ScannerModel:
    """The model a recorded Hokuyo describes: ``info`` (acq.records.DeviceInfo as a dict)
    and ``params`` (acq.drivers.scip_codec.ScipParams as a dict: PP in mm, steps, rpm)."""
    extra = info.get("extra", {})
    modl = str(params.get("model") or extra.get("PP.MODL") or "hokuyo")
    return ScannerModel(
        name=modl.split("(")[0].strip().lower() or "hokuyo",
        vendor="hokuyo",
        protocol="scip2.2" if "2.2" in extra.get("VV.PROT", "") else "scip2.0",
        product=str(info.get("model", "")),
        firmware=str(info.get("firmware", "")),
        serial=str(info.get("serial", "")),
        range_min=int(params["dmin"]) / 1000.0,
        range_max=int(params["dmax"]) / 1000.0,
        scan_hz=int(params["scan_rpm"]) / 60.0,
        intensity=True,  # any scan command passes the model's gate; the echo check decides
        multi_echo=True,
        amin=int(params["amin"]),
        amax=int(params["amax"]),
        afrt=int(params["afrt"]),
        ares=int(params["ares"]),
        serial_port=True,
        ethernet=True,
    )


class _RecordedTicks:
    """The device clock of a replayed Hokuyo, for TM and II TIME answers.

    The latest tick consistent with every telegram's receipt (of the first 200): the
    stamp of the least delayed telegram plus the log time since its receipt, on the
    replay's time axis (so it runs ``speed`` times fast in host time). Duck-types
    :class:`acq.sim.device_clock.SimClock` as far as :class:`ScipDevice` uses it.
    """

    epoch = 0.0

    def __init__(self, stream: ReplayStream, tick_hz: float, bits: int) -> None:
        self.stream = stream
        self.tick_hz = tick_hz
        self.bits = bits
        wrap, half = 1 << bits, 1 << (bits - 1)
        first = stream.head(200)
        k0, r0 = _scip_tick(first[0]), stream.first_ns
        best = 0.0
        for data, r in zip(first, stream.times_ns[:200].tolist(), strict=False):
            dk = (_scip_tick(data) - k0 + half) % wrap - half
            best = max(best, dk - (r - r0) * 1e-9 * tick_hz)
        self._k0 = k0 + best
        self._r0 = r0

    def ticks(self, t: float) -> int:
        clock = self.stream.clock
        if not clock.started:
            self.stream.start_clock(t)
        elapsed = (clock.log_ns_at(t) - self._r0) * 1e-9 * self.tick_hz
        return math.floor(self._k0 + elapsed) % (1 << self.bits)

    def reboot(self, t: float) -> None:
        """A replayed device's clock is the recorded one, whatever happens to the link."""


def _scip_tick(telegram: bytes) -> int:
    """The 4-character time stamp of a SCIP scan telegram (third line)."""
    lines = telegram.split(b"\n", 3)
    if len(lines) < 4 or len(lines[2]) != 5:
        raise ProtocolError(f"not a SCIP scan telegram: {telegram[:24]!r}")
    return decode_int(lines[2][:4])


class ScipReplayDevice(ScipDevice):
    """A Hokuyo that streams recorded SCIP telegrams (see the module doc).

    ``info``/``params``: the recorded ``device.<name>`` metadata (DeviceInfo, ScipParams
    as dicts). VV/PP/II answer what the device answered then (II's TIME from the recorded
    clock, LASR from the current state). The recorded scan command gets the recorded
    telegrams byte for byte; another request for the same data (see ``_served_form``:
    e.g. a client's ``GD`` single scans or ``MD`` with cluster 00 from a recorded ``MD``
    with cluster 01) gets the recorded telegrams under its own echo; any other is refused.
    """

    def __init__(
        self,
        stream: ReplayStream,
        info: dict[str, Any],
        params: dict[str, Any],
        report: Report = _ignore,
    ) -> None:
        self.stream = stream
        self.report = report
        self.echo = stream.head(1)[0].split(b"\n", 1)[0]
        self.recorded_info = info
        model = scip_model(info, params)
        ticks = _RecordedTicks(stream, model.clock_hz, model.clock_bits)
        super().__init__(model, source=_NoSource(), clock=ticks)  # type: ignore[arg-type]
        self._reported: set[bytes] = set()
        self.recorded = parse_scan_echo(self.echo)
        self._form: _Form | None = None  # how a streamed request differs from the recording

    # --- SimDevice ------------------------------------------------------------------------

    def poll(self, now: float) -> bytes:
        if self._stream is None:
            return b""
        form = self._form
        if form is None:
            return b"".join(self.stream.take(now))
        out = bytearray()
        for telegram in self.stream.take(now):
            if form.finite:
                form.remaining -= 1
            out += _retold(telegram, form.echo(), None, form.cut)
            if form.finite and form.remaining == 0:
                self._stream = None
                self.laser = False
                self.stream.stop()
                break
        return bytes(out)

    def next_due(self, now: float) -> float | None:
        return None if self._stream is None else self.stream.due()

    def on_disconnect(self) -> None:
        super().on_disconnect()
        self.stream.stop()

    # --- replies ----------------------------------------------------------------------------

    def _reply(self, line: bytes, now: float) -> bytes:
        op = line[:2].decode("ascii", "replace")
        if op in ("II", "TM") or op in SCAN_COMMANDS:
            self.stream.start_clock(now)  # a time or data request starts the replay
        in_any_state = self.scip22 and line in (b"VV", b"II")
        items = None if self.tm_mode and not in_any_state else self._recorded_items(line, now)
        if items is not None:
            self.commands.append(line.decode("ascii", "replace"))
            return self._info(line, items)
        reply = super()._reply(line, now)
        if self._stream is None:
            self.stream.stop()
        return reply

    def _recorded_items(self, line: bytes, now: float) -> list[tuple[str, str]] | None:
        """VV/PP/II as the device answered when it was recorded (None: not one of them,
        or not recorded)."""
        if line not in (b"VV", b"PP", b"II"):
            return None
        prefix = line.decode("ascii") + "."
        extra: dict[str, str] = self.recorded_info.get("extra", {})
        items = [(k[3:], str(v)) for k, v in extra.items() if k.startswith(prefix)]
        if not items:
            return None
        if line == b"II":
            live = {"TIME": self._time_field(now), "LASR": "ON" if self.laser else "OFF"}
            items = [(k, live.get(k, v)) for k, v in items]
        return items

    def _scan_command(self, line: bytes, op: str, params: str, now: float) -> bytes:
        form = None if line == self.echo else self._served_form(line)
        if line != self.echo and form is None:
            if line not in self._reported:
                self._reported.add(line)
                self.report(
                    f"{self.stream.name}: the client asked for {line.decode('ascii', 'replace')}"
                    f" but the log holds {self.echo.decode('ascii', 'replace')} scans; a replay"
                    " serves only what was recorded: configure the client's scanner options"
                    " as in the recorded configuration"
                )
            return self._simple(line, "0E")
        if form is not None and not form.continuous:
            if not self.laser:
                return self._simple(line, "10")
            if self.stream.clock.log_ns_at(now) > self.stream.last_ns:
                return b""  # the log has ended: silent, like the streams
            return _retold(self.stream.latest(now), line, b"00", form.cut)
        reply = super()._scan_command(line, op, params, now)
        self._form = form
        if self._stream is not None:
            self.stream.begin(now)
        return reply

    def _served_form(self, line: bytes) -> _Form | None:
        """How to serve a scan request other than the recorded one from the recorded
        telegrams, or None when they do not hold its data. Served: a single scan (GD from
        a recorded MD, GE from ME, HD/HE from ND/NE); another scan count; cluster 00 for
        01; distances without the recorded intensities (MD from ME); fewer steps when each
        step was recorded on its own. Every value sent is a recorded one."""
        try:
            req = parse_scan_echo(line)
        except ProtocolError:
            return None
        rec = self.recorded
        width, intensity, multi, continuous = SCAN_COMMANDS[req.command]
        rec_width, rec_intensity, rec_multi, _ = SCAN_COMMANDS[rec.command]
        cluster = max(rec.cluster, 1)
        same_steps = (req.start, req.end) == (rec.start, rec.end)
        if (
            (width, multi) != (rec_width, rec_multi)
            or (intensity and not rec_intensity)
            or max(req.cluster, 1) != cluster
            or (continuous and req.interval != rec.interval)
            or not rec.start <= req.start <= req.end <= rec.end
            or (not same_steps and cluster != 1)
            or (multi and (intensity != rec_intensity or not same_steps))
        ):
            return None
        cut = None
        if not same_steps or intensity != rec_intensity:
            chars = width * (2 if rec_intensity else 1)
            steps = slice(req.start - rec.start, req.end - rec.start + 1)
            cut = _Cut(steps, chars, width * (2 if intensity else 1))
        text = b";" + req.text.encode() if req.text else b""
        return _Form(req.prefix(), text, cut, continuous, req.remaining, req.remaining > 0)


@dataclass(frozen=True)
class _Cut:
    """Part of each recorded step's characters: the steps asked for, and of each step's
    ``chars`` characters the first ``keep`` (the distance without the intensity)."""

    steps: slice
    chars: int
    keep: int

    def __call__(self, data: bytes) -> bytes:
        per_step = np.frombuffer(data, dtype=np.uint8).reshape(-1, self.chars)
        return per_step[self.steps, : self.keep].tobytes()


@dataclass
class _Form:
    """A streamed or polled request served from recorded telegrams of another echo."""

    prefix: bytes  # the client's echo up to its remaining-scans field
    text: bytes  # its ";string", if any
    cut: _Cut | None  # the part of the recorded scan data it asked for
    continuous: bool
    remaining: int  # scans left of a finite request
    finite: bool

    def echo(self) -> bytes:
        return self.prefix + f"{self.remaining:02d}".encode() + self.text


def _retold(telegram: bytes, echo: bytes, status: bytes | None, cut: _Cut | None) -> bytes:
    """A recorded scan telegram under another echo (and status, for a single scan), its
    data cut by ``cut``; the time stamp and the values are the recorded ones."""
    _echo, status_line, stamp, body = telegram.split(b"\n", 3)
    if status is not None:
        status_line = status + bytes([checksum(status)])
    if cut is not None:
        data = b"".join(line[:-1] for line in body.split(b"\n") if line)
        body = encode_lines(cut(data)) + b"\n"
    return echo + b"\n" + status_line + b"\n" + stamp + b"\n" + body


# --- CoLa -----------------------------------------------------------------------------------


def cola_model(
    info: dict[str, Any], geometry: dict[str, Any], recorded: ScanData | None = None
) -> ScannerModel:
    """The model a recorded SICK describes: ``info`` (DeviceInfo as a dict),
    ``geometry`` (acq.drivers.scanner.ScanGeometry as a dict: rad, s, m) and the first
    recorded scan (its channels: echoes, RSSI and its width). What the recording cannot
    tell (evaluation fields, the scan configurations a client may ask for) comes from the
    simulated model with the same product name, if any."""
    product = str(info.get("model", "")) or "LMS1xx"
    known = next((m for m in MODELS.values() if m.product == product), None)
    rssi = recorded.channel("RSSI1") if recorded is not None else None
    echoes = len(recorded.distance_channels()) if recorded is not None else 1
    return ScannerModel(
        name=product.lower(),
        vendor="sick",
        protocol="cola",
        product=product,
        firmware=str(info.get("firmware", "")),
        serial=str(info.get("serial", "")),
        range_min=float(geometry.get("range_min", 0.0)),
        range_max=max(float(geometry.get("range_max", 0.0)), 1.0),
        scan_hz=1.0 / float(geometry["scan_period"]),
        intensity=recorded is None or rssi is not None,
        start_deg=math.degrees(float(geometry["angle_min"])) + 90.0,
        step_deg=math.degrees(float(geometry["angle_increment"])),
        n_points=int(geometry["n_points"]),
        rssi_bits=8 if rssi is not None and rssi.data.dtype == np.uint8 else 16,
        echoes=max(echoes, known.echoes if known else 1),
        eval_fields=known.eval_fields if known else 48 if product.upper()[:4] == "TIM7" else 30,
        scan_configs=known.scan_configs if known else (),
        ethernet=True,
        clock_bits=32,
        clock_hz=1e6,
    )


def _recorded_shape(sd: ScanData) -> ScanShape:
    dist = sd.distance_channels()[0]
    rssi = [c for c in sd.channels if c.name.startswith("RSSI")]
    return ScanShape(
        sd.scan_frequency,
        dist.start_angle,
        dist.step,
        int(dist.data.size),
        len(sd.distance_channels()),
        len(rssi),
        (8 if rssi[0].data.dtype == np.uint8 else 16) if rssi else 0,
        1,
    )


class ColaReplayDevice(ColaDevice):
    """A SICK scanner that streams recorded ``sSN LMDscandata`` telegrams (CoLa-A or -B,
    as recorded: it powers up in the recorded encoding; a client that switches it to the
    other one gets the recorded scans in that one).

    The start-up (login, identity, scan and data configuration, fields) is answered as
    :class:`acq.sim.cola_device.ColaDevice` does, from the recorded identity, geometry
    and channels; what a client writes is kept as the device would. ``sEN LMDscandata 1``
    starts the recorded stream, ``sRN LMDscandata`` answers the latest recorded scan as
    ``sRA``, provided the configuration then asks for scans of the recorded shape
    (frequency, angles, points, channels); otherwise the client gets ``sFA`` and
    ``report`` says why: a replay serves only what was recorded.
    """

    def __init__(
        self,
        stream: ReplayStream,
        info: dict[str, Any],
        geometry: dict[str, Any],
        report: Report = _ignore,
    ) -> None:
        self.stream = stream
        self.report = report
        self.recorded_binary = stream.head(1)[0][:4] == STX4
        try:
            first: ScanData | None = parse_scandata(stream.head(1)[0])
        except ProtocolError:
            first = None
        model = cola_model(info, geometry, first)
        super().__init__(
            model,
            source=_NoSource(),
            clock=SimClock(tick_hz=model.clock_hz, wrap_bits=model.clock_bits),
            protocol="cola-b" if self.recorded_binary else "cola-a",
        )
        self.recorded_shape = None if first is None else _recorded_shape(first)
        if first is not None:
            self.default_data = replace(
                self.default_data,
                channels=(1 << len(first.distance_channels())) - 1,
                remission=model.intensity,
                remission_16bit=model.rssi_bits == 16,
                time=first.timestamp is not None,
            )
            self.default_echo_filter = 1 if len(first.distance_channels()) > 1 else 0
            self._reset()
        self._reported: set[str] = set()

    def poll(self, now: float) -> bytes:
        if not (self.streaming and self.measuring):
            return b""
        return b"".join(self._served(raw) for raw in self.stream.take(now))

    def next_due(self, now: float) -> float | None:
        if not (self.streaming and self.measuring):
            return None
        return self.stream.due()

    def _served(self, raw: bytes, kind: str = "sSN") -> bytes:
        """A recorded telegram as the device sends it now: the recorded bytes, or, once a
        client switched the encoding (``sWN EIHstCola``), the same scan (counters, ticks,
        values) in the new encoding, as the real device would send it."""
        if self.binary == self.recorded_binary and kind == "sSN":
            return raw
        tg = unframe(raw)
        if self.binary == self.recorded_binary:
            return self._frame(kind.encode() + tg.payload[3:])
        return self._frame(
            encode_scandata(parse_scandata(tg.payload, tg.binary), self.binary, kind)
        )

    def on_disconnect(self) -> None:
        super().on_disconnect()
        self.stream.stop()

    def _report_once(self, why: str) -> None:
        if why not in self._reported:
            self._reported.add(why)
            self.report(f"{self.stream.name}: {why}; a replay serves only what was recorded")

    def _answer(self, tg: Telegram, now: float) -> bytes:
        if tg.name == "LMDscandata" and tg.kind in ("sEN", "sRN"):
            self.stream.start_clock(now)
            shape = self.shape()
            if self.recorded_shape is not None and replace(shape, output_rate=1) != (
                self.recorded_shape
            ):
                self._report_once(
                    f"the client configured scans of {_describe(shape)} but the log holds"
                    f" {_describe(self.recorded_shape)}"
                )
                return self._error(4)
            if tg.kind == "sRN":
                if not self.measuring:
                    return self._error(4)
                return self._served(self.stream.latest(now), "sRA")
        reply = super()._answer(tg, now)
        if tg.kind == "sEN" and tg.name == "LMDscandata":
            if self.streaming:
                self.stream.begin(now)
            else:
                self.stream.stop()
        return reply


def _describe(s: ScanShape) -> str:
    rssi = f", {s.n_rssi} x {s.rssi_bits}-bit RSSI" if s.n_rssi else ", no RSSI"
    return (
        f"{s.n_points} points from {s.start / 10000:g} deg every {s.step / 10000:g} deg at"
        f" {s.frequency / 100:g} Hz, {s.n_dist} echo(es){rssi}"
    )


# --- MJPEG ----------------------------------------------------------------------------------


class _Sent:
    """What :class:`MjpegServer` reports about each frame; a replay only counts them."""

    def __init__(self) -> None:
        self.sent = 0

    def record(self, sequence: int, **fields: Any) -> None:
        if fields.get("status") == "sent":
            self.sent += 1


class ReplayMjpegServer(MjpegServer):
    """Serves a camera's recorded JPEG bytes as MJPEG over HTTP at their recorded times.

    As :class:`acq.sim.mjpeg_server.MjpegServer` (several clients, the same faults): every
    connected client gets each frame due while it is connected. The first client starts
    the shared clock; with no client connected, frames are not sent (and not kept).
    """

    def __init__(
        self, stream: ReplayStream, host: str = "127.0.0.1", port: int = 0, path: str = "/"
    ) -> None:
        super().__init__(_Sent(), host, port, path, late_s=math.inf)  # type: ignore[arg-type]
        self.stream = stream

    def _run(self) -> None:
        stream = self.stream
        sequence = 0
        while not self._stop.is_set():
            with self._lock:
                watched = bool(self._clients)
            now = time.monotonic()
            if watched and not stream.active:
                stream.begin(now)
            elif not watched and stream.active:
                stream.stop()
            due = stream.due()
            self._service(now + 0.01 if due is None else min(due, now + 0.01))
            if self._stop.is_set():
                return
            for jpeg in stream.take(time.monotonic()):
                self._deliver(SimFrame(sequence, jpeg, 0.0, time.monotonic(), 0.0))
                sequence += 1
