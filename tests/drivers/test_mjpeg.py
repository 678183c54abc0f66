"""The MJPEG-over-HTTP parsers (the response head, the multipart body) and the JPEG header
check: any bytes, in any split, give parts or a ProtocolError, at a bounded cost."""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from acq.drivers.errors import ProtocolError
from acq.drivers.mjpeg import (
    MAX_PREAMBLE,
    MultipartReader,
    Part,
    jpeg_size,
    parse_response_head,
)


def _stream(bodies: list[bytes], lengths: bool) -> bytes:
    out = b""
    for body in bodies:
        out += b"--bnd\r\nContent-Type: image/jpeg\r\n"
        if lengths:
            out += f"Content-Length: {len(body)}\r\n".encode()
        out += b"\r\n" + body + b"\r\n"
    return out + b"--bnd\r\n"


def _feed_split(reader: MultipartReader, data: bytes, cuts: list[int]) -> list[Part]:
    got: list[Part] = []
    last = 0
    for cut in [*sorted({min(c, len(data)) for c in cuts}), len(data)]:
        got += reader.feed(data[last:cut])
        last = cut
    return got


@settings(max_examples=300, deadline=None)
@given(
    bodies=st.lists(st.binary(max_size=300), min_size=1, max_size=5),
    lengths=st.booleans(),
    cuts=st.lists(st.integers(min_value=0, max_value=2000), max_size=8),
)
def test_parser_any_split(bodies: list[bytes], lengths: bool, cuts: list[int]) -> None:
    if not lengths:  # without a length, a body cannot hold the delimiter
        bodies = [b.replace(b"\n--bnd", b"\n-bnd") for b in bodies]
    got = _feed_split(MultipartReader(b"bnd"), _stream(bodies, lengths), cuts)
    assert [p.body for p in got] == bodies


@pytest.mark.parametrize(
    ("boundary", "data", "bodies", "finished"),
    [
        # junk lines, some holding the boundary deep inside, before the first delimiter
        (b"bnd", b"junk\r\nx--bnd\r\n  xx--bnd--\n\n--bnd\r\nContent-Length: 2\r\n\r\nab\r\n",
         [b"ab"], False),
        (b"bnd", b"----bnd\r\nContent-Length: 2\r\n\r\nab\r\nbnd \t\r\n\r\ncd\r\n--bnd--\r\n",
         [b"ab", b"cd"], True),
        (b"--bnd", b"--bnd\n\nab\n--bnd\n\ncd\n--bnd\n", [b"ab", b"cd"], False),
        (None, b"\r\n--learnt\r\nContent-Length: 1\r\n\r\na\r\n--learnt--\r\n", [b"a"], True),
        (b"bnd", b"--bnd\r\n\r\nab\r\n--bnd--", [b"ab"], False),  # the close line unfinished
    ],
)  # fmt: skip
def test_delimiter_forms_in_every_split(
    boundary: bytes | None, data: bytes, bodies: list[bytes], finished: bool
) -> None:
    for cut in range(len(data) + 1):
        reader = MultipartReader(boundary)
        got = _feed_split(reader, data, [cut])
        assert [p.body for p in got] == bodies, cut
        assert reader.finished == finished, cut


@pytest.mark.parametrize(
    "value",
    [b"4\xb2", b"\xb9", b"\xd9\xa4", b"4\xbc", b"+4", b"-4", b"4_0", b"0x4", b"4 4", b"",
     b"9" * 5000, b"99999999999"],
)  # fmt: skip
def test_content_length_is_ascii_digits(value: bytes) -> None:
    """``str.isdigit`` takes superscripts and other digits, ``int`` does not: such a length
    is the parser's error, not a ValueError."""
    reader = MultipartReader(b"frame")
    with pytest.raises(ProtocolError, match="Content-Length"):
        reader.feed(b"--frame\r\nContent-Length: " + value + b"\r\n\r\nabcd\r\n")
    assert MultipartReader(b"frame").feed(b"--frame\r\nContent-Length:  4 \r\n\r\nabcd\r\n")


@pytest.mark.parametrize(
    "head",
    [b"HTTP/1.1 " + b"2" * 5000 + b" OK", b"HTTP/1.1 2\xb200 OK", b"HTTP/1.1 +20 OK",
     b"HTTP/1.1 2000 OK", b"HTTP/1.1", b"", b"ICY 200 OK",
     b"HTTP/1.0 200 OK\r\n" + b"X: y\r\n" * 100],
)  # fmt: skip
def test_bad_response_heads(head: bytes) -> None:
    with pytest.raises(ProtocolError, match="HTTP response"):
        parse_response_head(head)


def test_response_head() -> None:
    status, reason, headers = parse_response_head(
        b"HTTP/1.0 200 OK\r\nContent-Type: multipart/x-mixed-replace; boundary=x\r\nA:\r\n"
    )
    assert (status, reason) == (200, "OK")
    assert headers == {"content-type": "multipart/x-mixed-replace; boundary=x", "a": ""}


# --- fuzz: any bytes give parts or a ProtocolError -----------------------------------------

_VALUES = st.one_of(
    st.binary(max_size=8),
    st.integers(min_value=0, max_value=400).map(lambda n: str(n).encode()),
    st.sampled_from([b"4\xb2", b"\xb3", b"1\xb9", b"\xd9\xa4", b"+3", b"3_0", b"0" * 30]),
)
_HEADER = st.tuples(
    st.sampled_from([b"Content-Length", b"Content-Type", b"X-Ts", b"", b"\xff"]), _VALUES
).map(lambda nv: nv[0] + b": " + nv[1])
_DELIMITER = st.sampled_from([b"--bnd", b"----bnd", b"bnd", b"--bnd--", b"--bnd  ", b"x--bnd"])
_PART = st.tuples(
    _DELIMITER, st.lists(_HEADER, max_size=3), st.binary(max_size=60), st.binary(max_size=6)
)


@settings(max_examples=250, deadline=None)
@given(
    parts=st.lists(_PART, max_size=5),
    eol=st.sampled_from([b"\r\n", b"\n"]),
    boundary=st.sampled_from([None, b"bnd", b"--bnd"]),
    cuts=st.lists(st.integers(min_value=0, max_value=600), max_size=6),
)
def test_parser_fuzz_structured(
    parts: list[tuple[bytes, list[bytes], bytes, bytes]],
    eol: bytes,
    boundary: bytes | None,
    cuts: list[int],
) -> None:
    """Streams shaped like MJPEG with odd delimiters, header values (lengths in other
    digits, signs, too long) and junk, cut anywhere: parts or ProtocolError only."""
    data = b"".join(
        d + eol + b"".join(h + eol for h in headers) + eol + body + eol + junk
        for d, headers, body, junk in parts
    )
    reader = MultipartReader(boundary)
    try:
        got = _feed_split(reader, data, cuts)
    except ProtocolError:
        return
    assert all(isinstance(p, Part) and isinstance(p.body, bytes) for p in got)
    assert reader.parts == len(got)


@settings(max_examples=200, deadline=None)
@given(data=st.binary(max_size=3000), boundary=st.sampled_from([None, b"bnd", b"--bnd"]))
def test_parser_any_bytes(data: bytes, boundary: bytes | None) -> None:
    reader = MultipartReader(boundary)
    try:
        for i in range(0, len(data), 97):
            for part in reader.feed(data[i : i + 97]):
                assert isinstance(part.body, bytes)
    except ProtocolError:
        pass


@settings(max_examples=200, deadline=None)
@given(prefix=st.binary(max_size=200), junk=st.binary(max_size=2000))
def test_parser_garbage_after_valid(prefix: bytes, junk: bytes) -> None:
    reader = MultipartReader(b"bnd")
    try:
        reader.feed(_stream([prefix], True) + junk)
    except ProtocolError:
        pass


@settings(max_examples=250, deadline=None)
@given(
    status=st.one_of(st.binary(max_size=6), st.sampled_from([b"200", b"2\xb20", b"\xd9\xa4"])),
    rest=st.binary(max_size=300),
    any_head=st.binary(max_size=300),
)
def test_response_head_fuzz(status: bytes, rest: bytes, any_head: bytes) -> None:
    for head in (b"HTTP/1.1 " + status + b" " + rest, any_head):
        try:
            code, reason, headers = parse_response_head(head)
        except ProtocolError:
            continue
        assert 0 <= code <= 999 and isinstance(reason, str) and isinstance(headers, dict)


# --- the cost of junk ---------------------------------------------------------------------


def test_junk_between_parts_costs_little() -> None:
    """Lines that cannot be a delimiter are skipped in bulk (1 MB of blank lines in a
    few ms of CPU), and lines holding the boundary that are not a delimiter are looked
    at only so many times before the stream is an error."""
    reader = MultipartReader(b"bnd")
    t0 = time.thread_time()
    with pytest.raises(ProtocolError, match="no boundary"):
        for _ in range(2 * MAX_PREAMBLE // 65536):
            reader.feed(b"\r\n" * 32768)
    assert time.thread_time() - t0 < 0.25

    reader = MultipartReader(b"bnd")
    fed = 0
    with pytest.raises(ProtocolError, match="not a delimiter"):
        while fed < 2 * MAX_PREAMBLE:
            reader.feed(b"x--bnd\r\n" * 512)
            fed += 4096
    assert fed <= 4 * 4096


# --- the JPEG header check ----------------------------------------------------------------


@settings(max_examples=300, deadline=None)
@given(data=st.binary(max_size=600))
def test_jpeg_size_any_bytes(data: bytes) -> None:
    try:
        w, h = jpeg_size(b"\xff\xd8" + data)
        assert w > 0 and h > 0
    except ProtocolError:
        pass


def test_jpeg_size_real_and_broken() -> None:
    _, buf = cv2.imencode(".jpg", np.zeros((37, 53, 3), np.uint8))
    data = buf.tobytes()
    assert jpeg_size(data) == (53, 37)
    assert jpeg_size(data + b"\r\n") == (53, 37)
    _, buf = cv2.imencode(
        ".jpg", np.zeros((37, 53, 3), np.uint8), [cv2.IMWRITE_JPEG_PROGRESSIVE, 1]
    )
    assert jpeg_size(buf.tobytes()) == (53, 37)
    for broken in (data[: len(data) // 2], data[2:], data[:20] + data[-2:], b""):
        with pytest.raises(ProtocolError):
            jpeg_size(broken)


_FISHEYE = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "fisheye"
_CAPTURES = [p.read_bytes() for p in sorted(_FISHEYE.glob("*.jpg"))] if _FISHEYE.is_dir() else []


@pytest.mark.skipif(not _CAPTURES, reason="no fisheye JPEGs in ../shared/data/fisheye")
@settings(max_examples=60, deadline=None)
@given(
    lengths=st.booleans(),
    cuts=st.lists(st.integers(min_value=0, max_value=900_000), max_size=40),
)
def test_real_captures_come_out_byte_for_byte_in_any_split(lengths: bool, cuts: list[int]) -> None:
    """The real fisheye JPEGs (150-180 kB each), streamed twice over, cut anywhere: each
    part is the JPEG as sent, and its size is read from its header."""
    bodies = _CAPTURES * 2
    got = _feed_split(MultipartReader(b"bnd"), _stream(bodies, lengths), cuts)
    assert [p.body for p in got] == bodies
    assert all(type(p.body) is bytes for p in got)
    assert {jpeg_size(p.body) for p in got} == {jpeg_size(_CAPTURES[0])}
