"""MJPEG over HTTP: the response head, the ``multipart/x-mixed-replace`` parts, JPEG checks.

Sans-I/O: :class:`MultipartReader` is fed bytes in any split and hands back complete
parts (their headers and body exactly as sent). A part with ``Content-Length`` is cut
at that length; one without is cut at the next boundary delimiter (RFC 2046). Every
buffer is bounded, so any byte string gives parts or :class:`ProtocolError`, never an
unbounded wait for data that cannot come.

:func:`jpeg_size` reads a JPEG's width and height from its SOF header and checks its
markers (SOI first, a parsable header up to SOS, EOI last) without decoding the image.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

from acq.drivers.errors import ProtocolError

__all__ = [
    "MAX_HEAD",
    "MAX_PART",
    "MultipartReader",
    "Part",
    "boundary_of",
    "jpeg_size",
    "parse_response_head",
]

MAX_HEAD = 16 * 1024  # bytes: an HTTP head or a part's headers longer than this is an error
MAX_HEADER_LINES = 64  # header lines in an HTTP head or a part's headers
MAX_PART = 32 * 1024 * 1024  # bytes: the largest part (a 4K JPEG is a few MB)
MAX_PREAMBLE = 1024 * 1024  # bytes of junk tolerated between parts
_MAX_LENGTH_DIGITS = len(str(MAX_PART))

_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


@dataclass(frozen=True)
class Part:
    """One body part: its headers (names lower-cased) and its bytes as sent."""

    headers: dict[str, str]
    body: bytes


def _parse_headers(lines: list[bytes], where: str) -> dict[str, str]:
    headers: dict[str, str] = {}
    for line in lines:
        name, sep, value = line.partition(b":")
        if not sep or not name.strip():
            raise ProtocolError(f"{where}: malformed header line {line[:60]!r}")
        try:
            key = name.strip().decode("ascii").lower()
        except UnicodeDecodeError:
            raise ProtocolError(f"{where}: non-ASCII header name {name[:60]!r}") from None
        headers[key] = value.strip().decode("latin-1")
    return headers


def _ascii_int(text: bytes, max_digits: int) -> int | None:
    """``text`` as a decimal of 1 to ``max_digits`` ASCII digits, else None (``int()`` and
    ``isdigit()`` take other Unicode digits, spaces, signs and underscores)."""
    if not 0 < len(text) <= max_digits or not text.isdigit():  # bytes: ASCII digits only
        return None
    return int(text)


def parse_response_head(head: bytes) -> tuple[int, str, dict[str, str]]:
    """An HTTP response head (up to, not including, the blank line) -> (status, reason,
    headers with lower-case names); ProtocolError for anything else."""
    if len(head) > MAX_HEAD:
        raise ProtocolError(f"HTTP response: head over {MAX_HEAD} bytes")
    lines = head.split(b"\r\n") if b"\r\n" in head else head.split(b"\n")
    if len(lines) > MAX_HEADER_LINES + 1:
        raise ProtocolError(f"HTTP response: over {MAX_HEADER_LINES} header lines")
    status_line = lines[0]
    parts = status_line.split(None, 2)
    status = _ascii_int(parts[1], 3) if len(parts) >= 2 else None
    if status is None or not parts[0].startswith(b"HTTP/") or len(parts[1]) != 3:
        raise ProtocolError(f"HTTP response: bad status line {status_line[:80]!r}")
    reason = parts[2].decode("latin-1") if len(parts) > 2 else ""
    return status, reason, _parse_headers([x for x in lines[1:] if x], "HTTP response")


def boundary_of(content_type: str) -> bytes | None:
    """The boundary parameter of a ``multipart/...`` Content-Type, None when absent."""
    for param in content_type.split(";")[1:]:
        key, sep, value = param.strip().partition("=")
        if sep and key.strip().lower() == "boundary":
            value = value.strip().strip('"')
            if value:
                return value.encode("latin-1")
    return None


@dataclass
class MultipartReader:
    """Incremental parser of a ``multipart/x-mixed-replace`` body.

    ``boundary`` as in the Content-Type (with or without the leading ``--`` that some
    cameras put there); None: learnt from the first line that starts with ``--``.

    The work is bounded per byte received: lines that cannot be a delimiter are skipped
    in bulk, and between two parts at most :data:`MAX_PREAMBLE` bytes and
    ``MAX_CANDIDATES`` lines holding the boundary are looked at. :meth:`push` and
    :meth:`next_part` let a caller stop after the parts it wants.
    """

    MAX_CANDIDATES: ClassVar[int] = 256  # boundary strings between parts, not delimiters

    boundary: bytes | None = None
    parts: int = 0  # complete parts seen
    finished: bool = False  # the close delimiter ``--boundary--`` arrived
    _buf: bytearray = field(default_factory=bytearray)
    _state: str = "preamble"  # preamble | headers | body
    _headers: dict[str, str] = field(default_factory=dict)
    _length: int | None = None
    _scan_from: int = 0  # body: where to look for the delimiter; preamble: the boundary
    _consumed: int = 0  # bytes consumed before _buf[0], for error offsets
    _junk: int = 0  # bytes skipped since the last part while looking for a delimiter
    _candidates: int = 0  # boundary strings looked at since the last part
    _head_bytes: int = 0  # bytes of the current part's headers
    _head_lines: int = 0

    def __post_init__(self) -> None:
        if self.boundary is not None:
            self.boundary = self._strip(self.boundary)

    @staticmethod
    def _strip(boundary: bytes) -> bytes:
        b = boundary[2:] if boundary.startswith(b"--") and len(boundary) > 2 else boundary
        if not b or len(b) > 200 or b"\r" in b or b"\n" in b:
            raise ProtocolError(f"multipart: invalid boundary {boundary[:80]!r}")
        return b

    def _is_boundary(self, line: bytes) -> bool | None:
        """True: a delimiter line; None: the close delimiter; False: something else."""
        line = line.rstrip(b" \t")
        if self.boundary is None:
            if line.startswith(b"--") and len(line) > 2:
                self.boundary = self._strip(line[2:])
            else:
                return False
        b = self.boundary
        if line in (b"--" + b, b"----" + b, b):
            return True
        if line in (b"--" + b + b"--", b"----" + b + b"--", b + b"--"):
            return None
        return False

    def _take(self, n: int) -> bytes:
        """The first ``n`` bytes, removed from the buffer: one copy (a slice of the
        bytearray would be a second), through a view released before the buffer shrinks."""
        with memoryview(self._buf) as view, view[:n] as head:
            out = bytes(head)
        del self._buf[:n]
        self._consumed += n
        return out

    def _skip(self, n: int) -> None:
        """Drop ``n`` bytes of junk between parts."""
        del self._buf[:n]
        self._consumed += n
        self._junk += n
        if self._junk > MAX_PREAMBLE:
            raise ProtocolError(
                f"multipart: no boundary within {MAX_PREAMBLE} bytes (offset {self._consumed})"
            )

    def _line(self, limit: int, what: str) -> bytes | None:
        """The next line without its end, or None when incomplete."""
        end = self._buf.find(b"\n")
        if end < 0:
            if len(self._buf) > limit:
                raise ProtocolError(
                    f"multipart: {what} longer than {limit} bytes at offset {self._consumed}"
                )
            return None
        line = self._take(end + 1)[:-1]
        return line[:-1] if line.endswith(b"\r") else line

    def _delimiter_line(self) -> bytes | None:
        """Skips what cannot be a delimiter (a line without the boundary string within its
        first 4 bytes) in bulk; the next line that may be one, or None when more bytes are
        needed. The buffer starts at a line start, and ``buf[:_scan_from]`` holds no line
        end and no boundary string not yet looked at."""
        buf = self._buf
        while True:
            token = self.boundary if self.boundary is not None else b"--"
            at = buf.find(token, self._scan_from)
            nl = buf.rfind(b"\n", self._scan_from, at if at >= 0 else len(buf))
            if nl >= 0:  # whole lines before the boundary string (or all, without one)
                self._skip(nl + 1)
                at = at - nl - 1 if at >= 0 else at
                self._scan_from = 0
            if at < 0:  # the unfinished line is junk so far
                if self._junk + len(buf) > MAX_PREAMBLE:
                    self._skip(len(buf))
                self._scan_from = max(self._scan_from, len(buf) - len(token) + 1)
                return None
            end = buf.find(b"\n", at)
            if at > 4:  # deep inside its line: not a delimiter
                self._candidate()
                if end < 0:
                    self._scan_from = at + 1
                    continue
                self._skip(end + 1)
                self._scan_from = 0
                continue
            if end < 0:
                if len(buf) > MAX_HEAD:
                    raise ProtocolError(
                        f"multipart: line of over {MAX_HEAD} bytes at offset {self._consumed}"
                    )
                self._scan_from = at
                return None
            self._scan_from = 0
            line = self._take(end + 1)[:-1]
            self._junk += len(line) + 1
            return line[:-1] if line.endswith(b"\r") else line

    def _candidate(self) -> None:
        self._candidates += 1
        if self._candidates > self.MAX_CANDIDATES:
            raise ProtocolError(
                f"multipart: {self._candidates} boundary strings that are not a delimiter "
                f"(offset {self._consumed})"
            )

    def push(self, data: bytes) -> None:
        """Bytes as received, kept for :meth:`next_part`."""
        if not self.finished:
            self._buf += data

    def next_part(self) -> Part | None:
        """The next complete part of the bytes pushed so far, None when there is none."""
        while not self.finished:
            if self._state == "preamble":
                line = self._delimiter_line()
                if line is None:
                    return None
                kind = self._is_boundary(line)
                if kind is None:
                    self.finished = True
                elif kind:
                    self._state, self._headers = "headers", {}
                    self._head_bytes = self._head_lines = 0
                    self._junk = self._candidates = 0
                else:
                    self._candidate()
            elif self._state == "headers":
                line = self._line(MAX_HEAD, "part header")
                if line is None:
                    return None
                self._head_bytes += len(line) + 2
                self._head_lines += 1
                if self._head_bytes > MAX_HEAD or self._head_lines > MAX_HEADER_LINES + 1:
                    raise ProtocolError(
                        f"multipart: part headers over {MAX_HEAD} bytes or "
                        f"{MAX_HEADER_LINES} lines (offset {self._consumed})"
                    )
                if line:
                    self._headers.update(_parse_headers([line], "multipart part"))
                    continue
                self._length = None
                text = self._headers.get("content-length")
                if text is not None:
                    length = _ascii_int(text.encode("latin-1"), _MAX_LENGTH_DIGITS)
                    if length is None or length > MAX_PART:
                        raise ProtocolError(f"multipart: bad Content-Length {text[:40]!r}")
                    self._length = length
                self._state, self._scan_from = "body", 0
            else:  # body
                if self._length is not None:
                    if len(self._buf) < self._length:
                        return None
                    body = self._take(self._length)
                    # skip the CRLF and find the next delimiter
                    self._state, self._scan_from = "preamble", 0
                    self.parts += 1
                    return Part(self._headers, body)
                assert self.boundary is not None
                delim = b"\r\n--" + self.boundary
                at = self._buf.find(delim, self._scan_from)
                if at < 0:
                    # the bare-LF form, as some cameras send
                    at = self._buf.find(b"\n--" + self.boundary, self._scan_from)
                if at < 0:
                    if len(self._buf) > MAX_PART:
                        raise ProtocolError(
                            f"multipart: part without boundary over {MAX_PART} bytes"
                        )
                    self._scan_from = max(0, len(self._buf) - len(delim))
                    return None
                body = self._take(at)
                self._state, self._scan_from = "preamble", 0
                self.parts += 1
                return Part(self._headers, body)
        return None

    def feed(self, data: bytes) -> list[Part]:
        """Bytes as received -> the parts they complete (possibly none)."""
        self.push(data)
        out: list[Part] = []
        while (part := self.next_part()) is not None:
            out.append(part)
        return out


def jpeg_size(data: bytes) -> tuple[int, int]:
    """(width, height) px of a baseline or progressive JPEG; ProtocolError when the bytes
    do not start with SOI, end with EOI (trailing CR/LF/NUL padding allowed), or the
    header segments up to SOS do not parse or hold no frame header."""
    n = len(data)
    if n < 4 or data[0] != 0xFF or data[1] != 0xD8:
        raise ProtocolError("JPEG: no SOI marker at the start")
    end = n
    while end > 2 and data[end - 1] in (0x0D, 0x0A, 0x00, 0x20):
        end -= 1
    if end < 4 or data[end - 2] != 0xFF or data[end - 1] != 0xD9:
        raise ProtocolError("JPEG: no EOI marker at the end (truncated)")
    i = 2
    size: tuple[int, int] | None = None
    while i + 4 <= end:
        if data[i] != 0xFF:
            raise ProtocolError(f"JPEG: expected a marker at offset {i}")
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in (0x01, *range(0xD0, 0xD8)):  # TEM, RSTn: no length
            i += 2
            continue
        if marker in (0xD8, 0xD9):
            raise ProtocolError(f"JPEG: unexpected marker FF{marker:02X} at offset {i}")
        length = (data[i + 2] << 8) | data[i + 3]
        if length < 2 or i + 2 + length > end:
            raise ProtocolError(f"JPEG: segment FF{marker:02X} at offset {i} overruns the data")
        if marker in _SOF:
            if length < 8:
                raise ProtocolError(f"JPEG: short frame header at offset {i}")
            height = (data[i + 5] << 8) | data[i + 6]
            width = (data[i + 7] << 8) | data[i + 8]
            if width == 0 or height == 0:
                raise ProtocolError(f"JPEG: frame header with size {width}x{height}")
            size = (width, height)
        if marker == 0xDA:  # SOS: entropy-coded data follows
            if size is None:
                raise ProtocolError("JPEG: scan before any frame header")
            return size
        i += 2 + length
    raise ProtocolError("JPEG: no scan (SOS) in the header")
