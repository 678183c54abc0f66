"""SICK CoLa-A / CoLa-B: framing and argument coding (the scan telegram: cola_scandata).

Pure functions and small classes, no I/O: the driver (:mod:`acq.drivers.cola`) and the
simulated device (:mod:`acq.sim.cola_device`) share them, and the tests check them against a
real LMS111 capture.

Wire formats
------------
* **CoLa-A** (ASCII): ``STX (0x02) payload ETX (0x03)``; the payload is space-separated
  tokens. Numbers are hex (signed ones in two's complement of their width, floats as the
  hex of their IEEE-754 bits); a token starting with ``+`` or ``-`` is decimal. A string
  is a length token followed by exactly that many characters (which may hold spaces).
* **CoLa-B** (binary): ``02 02 02 02``, a big-endian uint32 payload length, the payload,
  and one XOR checksum byte over the payload. Numbers are big-endian, a string is a
  length (uint16, or uint8 inside ``LMDscandata``) followed by its characters.

Every payload starts with a command type (``sRN sRA sWN sWA sMN sAN sEN sEA sSN sFA``),
a space and the command name; binary arguments follow after one more space.
"""

from __future__ import annotations

import struct
from collections import deque
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from acq.drivers.scanner import DeviceError, ProtocolError

__all__ = [
    "MAX_LENGTH",
    "SOPAS_ERRORS",
    "ArgReader",
    "ColaFramer",
    "Telegram",
    "build",
    "check_error",
    "checksum",
    "frame",
    "unframe",
]

STX = 0x02
ETX = 0x03
STX4 = b"\x02\x02\x02\x02"
MAX_LENGTH = 1 << 20  # bytes: longer CoLa-B lengths are framing errors

# SOPAS error codes carried by ``sFA`` answers.
SOPAS_ERRORS: dict[int, str] = {
    0: "ok",
    1: "access denied (log in with SetAccessMode first)",
    2: "unknown method index",
    3: "unknown variable index",
    4: "local condition failed (value out of range or device not ready)",
    5: "invalid data",
    6: "unknown error",
    7: "buffer overflow",
    8: "buffer underflow",
    9: "unknown type",
    10: "variable write access denied",
    11: "unknown command for name server",
    12: "unknown CoLa command",
    13: "method server busy",
    14: "flex array/string out of bounds",
    15: "unknown event index",
    16: "CoLa-A value overflow",
    17: "CoLa-A invalid character",
    18: "OSAI no message",
    19: "OSAI no answer message",
    20: "internal error",
    21: "hub address corrupted",
    22: "hub address decoding",
    23: "hub address exceeded",
    24: "hub address blank expected",
    25: "asynchronous methods are suppressed",
    26: "complex arrays not supported",
}


# --------------------------------------------------------------------------------------
# framing


def checksum(payload: bytes | bytearray | memoryview) -> int:
    """CoLa-B checksum: XOR of every payload byte."""
    if len(payload) < 64:
        x = 0
        for b in bytes(payload):
            x ^= b
        return x
    return int(np.bitwise_xor.reduce(np.frombuffer(payload, np.uint8)))


def frame(payload: bytes, binary: bool, *, corrupt: bool = False) -> bytes:
    """The payload framed for the wire; ``corrupt`` gives a wrong checksum (CoLa-B) or a
    broken ETX (CoLa-A), for fault injection."""
    if binary:
        cs = checksum(payload) ^ (0x5A if corrupt else 0)
        return STX4 + struct.pack(">I", len(payload)) + payload + bytes((cs,))
    return b"\x02" + payload + (b"\x02" if corrupt else b"\x03")


@dataclass(frozen=True, slots=True)
class Telegram:
    """One framed telegram: its payload, encoding, the raw bytes and the receive stamp."""

    payload: bytes
    binary: bool
    raw: bytes = b""
    stamp_ns: int = 0  # host monotonic ns when its last byte was read (0 if unknown)

    @property
    def kind(self) -> str:
        """Command type: ``sRA``, ``sSN``, ``sFA`` ..."""
        return self.payload[:3].decode("latin-1")

    @property
    def name(self) -> str:
        """Command name (``LMDscandata``); empty for ``sFA``."""
        end = self.payload.find(b" ", 4)
        end = len(self.payload) if end < 0 else end
        return self.payload[4:end].decode("latin-1")

    @property
    def args(self) -> bytes:
        """The argument bytes after ``type name ``."""
        if self.payload[:3] == b"sFA":
            return self.payload[3:].lstrip(b" ") if not self.binary else self.payload[4:]
        end = self.payload.find(b" ", 4)
        return b"" if end < 0 else self.payload[end + 1 :]

    def reader(self) -> ArgReader:
        return ArgReader(self.args, self.binary)


def unframe(raw: bytes) -> Telegram:
    """One complete framed telegram (either encoding) -> :class:`Telegram`."""
    framer = ColaFramer()
    framer.feed(raw)
    item = framer.pop()
    if item is None or framer.pending:
        raise ProtocolError(f"not one complete CoLa telegram ({len(raw)} bytes)")
    return item


class ColaFramer:
    """Cuts a byte stream (any chunking) into telegrams, resynchronising after garbage.

    ``mode``: ``"auto"`` (both encodings), ``"a"`` or ``"b"``. Bytes outside a telegram
    are skipped (counted in ``skipped``); a bad checksum, an impossible length or an
    interrupted telegram is queued as a :class:`ProtocolError`, which :meth:`pop` raises
    in order (the framer is already past the bad bytes, so reading can go on).
    """

    def __init__(self, mode: str = "auto", max_length: int = MAX_LENGTH) -> None:
        if mode not in ("auto", "a", "b"):
            raise ValueError(f"mode must be auto, a or b, not {mode!r}")
        self.mode = mode
        self.max_length = max_length
        self._buf = bytearray()
        self._out: deque[Telegram | ProtocolError] = deque()
        self.skipped = 0
        self.errors = 0
        self.offset = 0  # stream offset of the buffer's first byte

    @property
    def pending(self) -> int:
        """Bytes held, waiting for the rest of a telegram."""
        return len(self._buf)

    def reset(self) -> None:
        self._buf.clear()
        self._out.clear()

    def feed(self, data: bytes, stamp_ns: int = 0) -> None:
        self._buf += data
        self._scan(stamp_ns)

    def pop(self) -> Telegram | None:
        """The next telegram, None when none is complete; raises a queued ProtocolError."""
        if not self._out:
            return None
        item = self._out.popleft()
        if isinstance(item, ProtocolError):
            raise item
        return item

    def items(self) -> Iterator[Telegram | ProtocolError]:
        """Drain the queue without raising."""
        while self._out:
            yield self._out.popleft()

    def _error(self, msg: str, pos: int) -> None:
        self.errors += 1
        self._out.append(ProtocolError(f"{msg} at stream offset {self.offset + pos}"))

    def _scan(self, stamp_ns: int) -> None:
        buf = self._buf
        n = len(buf)
        pos = 0
        allow_a = self.mode != "b"
        allow_b = self.mode != "a"
        while pos < n:
            i = buf.find(b"\x02", pos)
            if i < 0:
                self.skipped += n - pos
                pos = n
                break
            self.skipped += i - pos
            pos = i
            avail = n - pos
            if allow_b:
                head = bytes(buf[pos : pos + 4])
                if head == STX4:
                    if avail >= 5 and buf[pos + 4] == STX:
                        # a stray 0x02 before a header (a length cannot start with 02)
                        self.skipped += 1
                        pos += 1
                        continue
                    if avail < 9:
                        break
                    (length,) = struct.unpack_from(">I", buf, pos + 4)
                    if length == 0 or length > self.max_length:
                        self._error(f"CoLa-B: impossible length {length}", pos)
                        pos += 1
                        continue
                    if buf[pos + 8] != 0x73:  # every payload starts with "s"
                        self._error("CoLa-B: payload does not start with a command type", pos)
                        pos += 1
                        continue
                    end = pos + 9 + length
                    if n < end:
                        break
                    payload = bytes(buf[pos + 8 : end - 1])
                    if checksum(payload) != buf[end - 1]:
                        self._error(
                            f"CoLa-B: bad checksum in {payload[: 3 + 1 + 20]!r} ({length} bytes)",
                            pos,
                        )
                        # Skip the whole telegram only when the next one starts right after.
                        follows = bytes(buf[end : end + 4])
                        pos = end if STX4.startswith(follows) else pos + 1
                        continue
                    self._out.append(Telegram(payload, True, bytes(buf[pos:end]), stamp_ns))
                    pos = end
                    continue
                if avail < 4 and STX4.startswith(head):
                    break  # maybe the start of a CoLa-B header
            if allow_a:
                if avail < 2:
                    break
                if buf[pos + 1] == 0x73:
                    j = buf.find(b"\x03", pos + 1)
                    k = buf.find(b"\x02", pos + 1, n if j < 0 else j)
                    if k >= 0:
                        self._error("CoLa-A: telegram interrupted by STX", pos)
                        self.skipped += k - pos
                        pos = k
                        continue
                    if j < 0:
                        if avail > self.max_length:
                            self._error("CoLa-A: no ETX within the length limit", pos)
                            pos += 1
                            continue
                        break
                    payload = bytes(buf[pos + 1 : j])
                    self._out.append(Telegram(payload, False, bytes(buf[pos : j + 1]), stamp_ns))
                    pos = j + 1
                    continue
            self.skipped += 1
            pos += 1
        if pos:
            del buf[:pos]
            self.offset += pos


# --------------------------------------------------------------------------------------
# arguments

_INT_FMT = {"u8": ">B", "i8": ">b", "u16": ">H", "i16": ">h", "u32": ">I", "i32": ">i"}
_WIDTH = {"u8": 8, "i8": 8, "u16": 16, "i16": 16, "u32": 32, "i32": 32}

_HEX_LUT = np.full(256, -1, dtype=np.int64)
for _i, _c in enumerate(b"0123456789ABCDEF"):
    _HEX_LUT[_c] = _i
for _i, _c in enumerate(b"abcdef"):
    _HEX_LUT[_c] = 10 + _i
_HEX_LUT[0x20] = 0


def _ascii_int(token: bytes, kind: str) -> int:
    """A CoLa-A number token -> int of ``kind`` (hex, or +/- decimal)."""
    try:
        if token[:1] in (b"+", b"-"):
            value = int(token, 10)
        else:
            if not token or len(token) > 16:
                raise ValueError
            value = int(token, 16)
            if kind[0] == "i" and value >= 1 << (_WIDTH[kind] - 1):
                value -= 1 << _WIDTH[kind]
    except ValueError:
        raise ProtocolError(f"CoLa-A: {token[:20]!r} is not a {kind} number") from None
    lo, hi = (
        (-(1 << (_WIDTH[kind] - 1)), (1 << (_WIDTH[kind] - 1)) - 1)
        if kind[0] == "i"
        else (0, (1 << _WIDTH[kind]) - 1)
    )
    if not lo <= value <= hi:
        raise ProtocolError(f"CoLa-A: {value} out of range for {kind}")
    return value


class ArgReader:
    """Reads typed arguments from a payload's argument bytes, in either encoding.

    Every method raises :class:`ProtocolError` on short or malformed input.
    """

    __slots__ = ("_spaces", "binary", "data", "pos")

    def __init__(self, data: bytes, binary: bool, pos: int = 0) -> None:
        self.data = data
        self.binary = binary
        self.pos = pos
        self._spaces: np.ndarray | None = None

    def at_end(self) -> bool:
        return self.pos >= len(self.data)

    def rest(self) -> bytes:
        return self.data[self.pos :]

    def _need(self, n: int, what: str) -> int:
        p = self.pos
        if p + n > len(self.data):
            raise ProtocolError(f"telegram ends inside {what} (byte {p} of {len(self.data)})")
        self.pos = p + n
        return p

    def token(self) -> bytes:
        """CoLa-A: the next space-separated token."""
        p = self.pos
        if p >= len(self.data):
            raise ProtocolError(f"telegram ends before token (byte {p})")
        end = self.data.find(b" ", p)
        if end < 0:
            end = len(self.data)
            self.pos = end
        else:
            self.pos = end + 1
        return self.data[p:end]

    def num(self, kind: str) -> int:
        """``kind``: u8 i8 u16 i16 u32 i32."""
        if self.binary:
            p = self._need(_WIDTH[kind] // 8, kind)
            return int(struct.unpack_from(_INT_FMT[kind], self.data, p)[0])
        return _ascii_int(self.token(), kind)

    def u8(self) -> int:
        return self.num("u8")

    def u16(self) -> int:
        return self.num("u16")

    def u32(self) -> int:
        return self.num("u32")

    def i16(self) -> int:
        return self.num("i16")

    def i32(self) -> int:
        return self.num("i32")

    def f32(self) -> float:
        """IEEE-754 float32 (CoLa-A: the hex of its bits)."""
        if self.binary:
            p = self._need(4, "float")
            return float(struct.unpack_from(">f", self.data, p)[0])
        bits = _ascii_int(self.token(), "u32")
        return float(struct.unpack(">f", struct.pack(">I", bits))[0])

    def fixed(self, n: int) -> str:
        """A string of known length ``n`` without a length field (CoLa-A: one token)."""
        if self.binary:
            p = self._need(n, f"{n}-character string")
            return self.data[p : p + n].decode("latin-1")
        return self.token().decode("latin-1")

    def string(self, length_kind: str = "u16") -> str:
        """A length-prefixed string (may hold spaces in CoLa-A)."""
        n = self.num(length_kind)
        p = self._need(n, f"{n}-character string")
        text = self.data[p : p + n].decode("latin-1")
        if not self.binary and self.pos < len(self.data):
            if self.data[self.pos] != 0x20:
                raise ProtocolError(f"CoLa-A: string of length {n} not followed by a space")
            self.pos += 1
        return text

    def array(self, n: int, kind: str) -> np.ndarray:
        """``n`` unsigned values (``u8`` | ``u16``) as a numpy array (big-endian view)."""
        if n == 0:
            return np.zeros(0, dtype=np.uint16 if kind == "u16" else np.uint8)
        if self.binary:
            size = 2 if kind == "u16" else 1
            p = self._need(n * size, f"{n} x {kind} channel data")
            return np.frombuffer(self.data, ">u2" if size == 2 else np.uint8, n, p)
        return self._ascii_array(n, kind)

    def _ascii_array(self, n: int, kind: str) -> np.ndarray:
        data = self.data
        if self._spaces is None:
            self._spaces = np.flatnonzero(np.frombuffer(data, np.uint8) == 0x20)
        spaces = self._spaces
        p = self.pos
        k = int(np.searchsorted(spaces, p))
        last = k + n - 1  # index of the space ending the n-th token
        if last < len(spaces):
            end = int(spaces[last])
            nxt = end + 1
        elif last == len(spaces):
            end = nxt = len(data)
        else:
            raise ProtocolError(f"CoLa-A: telegram ends inside {n} x {kind} channel data")
        seg = np.frombuffer(data, np.uint8, end - p, p)
        seps = spaces[k:last] - p
        starts = np.empty(n, dtype=np.int64)
        starts[0] = 0
        starts[1:] = seps + 1
        ends = np.empty(n, dtype=np.int64)
        ends[:-1] = seps
        ends[-1] = len(seg)
        lengths = ends - starts
        nib = _HEX_LUT[seg]
        if lengths.min() < 1 or lengths.max() > _WIDTH[kind] // 4 or (nib < 0).any():
            # Rare: decimal (+/-) tokens or bad input; the scalar path says which.
            out = np.array([_ascii_int(self.token(), kind) for _ in range(n)])
            return out.astype(np.uint16 if kind == "u16" else np.uint8)
        tid = np.repeat(np.arange(n), lengths + 1)[: len(seg)]
        shift = (ends[tid] - 1 - np.arange(len(seg))) * 4
        digits = np.where(seg == 0x20, 0, nib << np.maximum(shift, 0))
        values = np.add.reduceat(digits, starts)
        self.pos = nxt
        return values.astype(np.uint16 if kind == "u16" else np.uint8)


class ArgWriter:
    """Builds argument bytes in either encoding (the inverse of :class:`ArgReader`)."""

    def __init__(self, binary: bool) -> None:
        self.binary = binary
        self.parts: list[bytes] = []

    def num(self, kind: str, value: int) -> ArgWriter:
        if self.binary:
            self.parts.append(struct.pack(_INT_FMT[kind], value))
        else:
            self.parts.append(b"%X" % (value & ((1 << _WIDTH[kind]) - 1)))
        return self

    def f32(self, value: float) -> ArgWriter:
        if self.binary:
            self.parts.append(struct.pack(">f", value))
        else:
            self.parts.append(struct.pack(">f", value).hex().upper().encode())
        return self

    def fixed(self, text: str) -> ArgWriter:
        self.parts.append(text.encode("latin-1"))
        return self

    def string(self, text: str, length_kind: str = "u16") -> ArgWriter:
        raw = text.encode("latin-1")
        if self.binary:
            self.parts.append(struct.pack(_INT_FMT[length_kind], len(raw)) + raw)
        else:
            self.parts.append(b"%X %s" % (len(raw), raw))
        return self

    def array(self, values: np.ndarray, kind: str) -> ArgWriter:
        if self.binary:
            self.parts.append(
                np.asarray(values).astype(">u2" if kind == "u16" else np.uint8).tobytes()
            )
        elif len(values):
            self.parts.append(" ".join(map("{:X}".format, np.asarray(values).tolist())).encode())
        return self

    def getvalue(self) -> bytes:
        if self.binary:
            return b"".join(self.parts)
        return b" ".join(p for p in self.parts if p != b"")


def build(kind: str, name: str, args: Sequence[tuple[str, Any]] = (), *, binary: bool) -> bytes:
    """A request/answer payload: ``build("sMN", "SetAccessMode", [("u8", 3), ("u32", h)])``.

    Argument kinds: u8 i8 u16 i16 u32 i32 f32, ``str`` (uint16 length), ``fixed``.
    """
    w = ArgWriter(binary)
    for k, v in args:
        if k == "f32":
            w.f32(v)
        elif k == "str":
            w.string(v)
        elif k == "fixed":
            w.fixed(v)
        else:
            w.num(k, v)
    head = f"{kind} {name}".encode("latin-1")
    body = w.getvalue()
    return head + b" " + body if args else head


def check_error(tg: Telegram) -> None:
    """Raise :class:`DeviceError` for an ``sFA`` answer (the SOPAS error code mapped)."""
    if tg.payload[:3] != b"sFA":
        return
    args = tg.payload[3:]
    code = -1
    try:
        if tg.binary:
            body = args[1:] if args[:1] == b" " else args
            code = int.from_bytes(body[:2], "big") if body else -1
        else:
            code = int(args.strip() or b"-1", 16)
    except ValueError:
        pass
    text = SOPAS_ERRORS.get(code, "unknown error code")
    raise DeviceError(f"SICK device error {code} (sFA): {text}", status=f"sFA {code}")
