"""Decoding frames for colouring (acq.camera.jpeg): the same pixels as OpenCV, and any
bytes give an image or None."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from acq.camera.jpeg import decode_jpeg, decoded_frames


def _jpeg(image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90])
    assert ok
    return buf.tobytes()


def test_colour_and_grey_frames_decode_as_opencv_does() -> None:
    rng = np.random.default_rng(0)
    colour = rng.integers(0, 256, (58, 78, 3), dtype=np.uint8)
    for jpeg in (_jpeg(colour), _jpeg(colour[..., 0])):  # a grey JPEG too
        got = decode_jpeg(jpeg)
        want = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
        assert got is not None and got.shape == (58, 78, 3)
        np.testing.assert_array_equal(got, want)
    frames = [_jpeg(colour), b"", b"not a jpeg", _jpeg(colour)[:40]]
    out = list(decoded_frames(frames, np.arange(4), threads=2))
    assert out[0] is not None and out[1] is None and out[2] is None and out[3] is None


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=600))
def test_any_bytes_give_an_image_or_none(data: bytes) -> None:
    head = _jpeg(np.full((16, 16, 3), 90, np.uint8))[:200]
    for jpeg in (data, head + data):
        image = decode_jpeg(jpeg)
        assert image is None or (image.ndim == 3 and image.shape[2] == 3)


def test_a_transient_frame_is_the_same_image_in_this_threads_buffer() -> None:
    from acq.camera.jpeg import decode_jpeg_transient

    rng = np.random.default_rng(1)
    a = _jpeg(rng.integers(0, 256, (58, 78, 3), dtype=np.uint8))
    b = _jpeg(rng.integers(0, 256, (40, 30, 3), dtype=np.uint8))
    first = decode_jpeg_transient(a)
    assert first is not None
    np.testing.assert_array_equal(first, decode_jpeg(a))
    second = decode_jpeg_transient(b)  # a smaller frame: the same buffer
    assert second is not None and second.shape == (40, 30, 3)
    np.testing.assert_array_equal(second, decode_jpeg(b))
    assert np.shares_memory(first, second)
    grey = _jpeg(np.full((16, 16), 7, np.uint8))
    assert decode_jpeg_transient(b"") is None and decode_jpeg_transient(b"junk") is None
    third = decode_jpeg_transient(grey)
    assert third is not None and third.shape == (16, 16, 3)


def test_shared_decodes_decode_a_waiting_frame_once_for_every_use() -> None:
    """Uses asked of a frame while it waits join its decoding; a frame asked for again
    once decoded, or other bytes under the same key, are decoded anew; a frame that does
    not decode gives its uses None; a use's error goes to its own future only."""
    import threading
    from concurrent.futures import ThreadPoolExecutor

    from acq.camera.jpeg import SharedDecodes

    rng = np.random.default_rng(1)
    a = _jpeg(rng.integers(0, 256, (24, 32, 3), dtype=np.uint8))
    b = _jpeg(rng.integers(0, 256, (24, 32, 3), dtype=np.uint8))
    gate = threading.Event()
    with ThreadPoolExecutor(max_workers=1) as pool:
        pool.submit(gate.wait)  # the pool's one thread busy: what follows waits
        shared = SharedDecodes(pool)
        seen: list[np.ndarray] = []

        def mean(image: np.ndarray | None) -> float:
            assert image is not None
            seen.append(image.copy())
            return float(image.mean())

        def boom(image: np.ndarray | None) -> float:
            raise ValueError("a use's own error")

        first = shared.submit(("left", 1), a, mean)
        again = shared.submit(("left", 1), a, mean)
        failing = shared.submit(("left", 1), a, boom)
        other = shared.submit(("left", 1), b, mean)  # same key, other bytes
        broken = shared.submit(("left", 2), b"not a jpeg", lambda image: image is None)
        gate.set()
        assert first.result() == again.result() == float(decode_jpeg(a).mean())  # type: ignore[union-attr]
        assert other.result() == float(decode_jpeg(b).mean())  # type: ignore[union-attr]
        assert broken.result() is True
        with pytest.raises(ValueError, match="own error"):
            failing.result()
        later = shared.submit(("left", 1), a, mean)  # decoded already: decoded anew
        assert later.result() == first.result()
    assert shared.uses == 6 and shared.decodes == 4  # a once for three, b, junk, a again
    np.testing.assert_array_equal(seen[0], decode_jpeg(a))
