"""Partial decoding through the system libjpeg-turbo (bench/jpeg_partial.py): the pixels
asked for are simplejpeg's whole decode, byte for byte; a JPEG it does not take, or a
damaged one, is refused or said not decoded, and never reaches libjpeg's error handler."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import simplejpeg
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.bench_scripts import load

jpeg_partial = load("jpeg_partial")

pytestmark = pytest.mark.skipif(
    not jpeg_partial.available(), reason=f"no partial decoding: {jpeg_partial.why_unavailable()}"
)

H, W = 582, 780  # the demo's fisheye frames


def _frame(seed: int = 0) -> np.ndarray:
    """A textured frame (fine detail: every coefficient matters)."""
    rng = np.random.default_rng(seed)
    noise = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    return cv2.GaussianBlur(noise, (5, 5), 1.0)


def _jpeg(image: np.ndarray, *params: int) -> bytes:
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 92, *params])
    assert ok
    return buf.tobytes()


def _ask(rng: np.random.Generator) -> tuple[np.ndarray, int, int]:
    """Rows in a few runs (edges included at times) and a column range."""
    rows = np.zeros(H, dtype=bool)
    for _ in range(rng.integers(1, 5)):
        a = int(rng.integers(0, H))
        rows[a : a + int(rng.integers(1, 40))] = True
    x0 = int(rng.choice([0, rng.integers(0, W - 1)]))
    x1 = int(rng.choice([W, rng.integers(x0 + 1, W + 1)]))
    return rows, x0, x1


@pytest.mark.parametrize(
    "params",
    [
        (),  # 4:2:0, as the demo's frames
        (cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_422),
        (cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444),
        (cv2.IMWRITE_JPEG_RST_INTERVAL, 7),
    ],
    ids=["420", "422", "444", "restarts"],
)
def test_the_pixels_asked_for_are_the_whole_decodes(params: tuple[int, ...]) -> None:
    jpeg = _jpeg(_frame(), *params)
    header = jpeg_partial.plain_header(jpeg)
    assert header is not None and (header.width, header.height) == (W, H)
    whole = simplejpeg.decode_jpeg(jpeg, colorspace="BGR")
    rng = np.random.default_rng(1)
    before = jpeg_partial.errors_caught
    for _ in range(12):
        rows, x0, x1 = _ask(rng)
        out = np.zeros((H, W, 3), dtype=np.uint8)
        assert jpeg_partial.decode_rows(jpeg, header, rows, x0, x1, out)
        np.testing.assert_array_equal(out[rows, x0:x1], whole[rows, x0:x1])
        # rows not asked for, in iMCU rows not asked for, are not decoded
        step = header.imcu_rows
        idle = ~np.repeat(np.add.reduceat(rows, np.arange(0, H, step)) > 0, step)[:H]
        assert not out[idle].any()
    assert jpeg_partial.errors_caught == before


def test_jpegs_it_does_not_take_are_refused_by_the_header_check() -> None:
    image = _frame(2)
    progressive = _jpeg(image, cv2.IMWRITE_JPEG_PROGRESSIVE, 1)
    grey = _jpeg(image[..., 0])
    tall = _jpeg(image, cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_440)
    plain = _jpeg(image)
    for jpeg in (progressive, grey, tall, b"", b"\xff\xd8", plain[:300]):
        assert jpeg_partial.plain_header(jpeg) is None
    sos = plain.index(b"\xff\xda")
    assert jpeg_partial.plain_header(plain[: sos + 14]) is not None  # the header whole
    assert jpeg_partial.plain_header(plain[: sos + 13]) is None


def test_truncated_or_damaged_scan_data_is_said_not_decoded_or_decodes_as_simplejpeg() -> None:
    jpeg = _jpeg(_frame(3))
    header = jpeg_partial.plain_header(jpeg)
    assert header is not None
    every = np.ones(H, dtype=bool)
    out = np.zeros((H, W, 3), dtype=np.uint8)
    cut = jpeg[: len(jpeg) // 2]
    assert not jpeg_partial.decode_rows(cut, header, every, 0, W, out)  # libjpeg warned
    top = np.zeros(H, dtype=bool)
    top[:16] = True  # read before the cut: decoded, as a whole decode has it
    assert jpeg_partial.decode_rows(cut, header, top, 0, W, out)
    lenient = simplejpeg.decode_jpeg(cut, colorspace="BGR", strict=False)
    np.testing.assert_array_equal(out[:16], lenient[:16])
    rng = np.random.default_rng(4)
    start = jpeg.index(b"\xff\xda") + 14
    before = jpeg_partial.errors_caught
    for _ in range(20):
        bad = bytearray(jpeg)
        for at in rng.integers(start, len(jpeg) - 2, 8):
            bad[at] = int(rng.integers(0, 256))
        out[:] = 0
        if jpeg_partial.decode_rows(bytes(bad), header, every, 0, W, out):
            lenient = simplejpeg.decode_jpeg(bytes(bad), colorspace="BGR", strict=False)
            np.testing.assert_array_equal(out, lenient)
    assert jpeg_partial.errors_caught == before


_SMALL = cv2.imencode(".jpg", _frame(5)[:40, :56], [cv2.IMWRITE_JPEG_QUALITY, 80])[1].tobytes()
_HEAD = _SMALL.index(b"\xff\xda") + 14


@settings(max_examples=400, deadline=None)
@given(st.lists(st.tuples(st.integers(0, _HEAD - 1), st.integers(0, 255)), min_size=1, max_size=4))
def test_a_damaged_header_is_refused_or_decodes_without_an_error(
    changes: list[tuple[int, int]],
) -> None:
    bad = bytearray(_SMALL)
    for at, value in changes:
        bad[at] = value
    header = jpeg_partial.plain_header(bytes(bad))
    if header is None or header.width * header.height > 2**22:
        return
    before = jpeg_partial.errors_caught
    out = np.zeros((header.height, header.width, 3), dtype=np.uint8)
    rows = np.ones(header.height, dtype=bool)
    jpeg_partial.decode_rows(bytes(bad), header, rows, 0, header.width, out)
    assert jpeg_partial.errors_caught == before
