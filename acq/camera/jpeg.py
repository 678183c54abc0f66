"""JPEG frames decoded for colouring: one at a time, or a sequence on a few threads.

Decoding is most of `acq colorize`'s work. simplejpeg (libjpeg-turbo's own API, without
OpenCV's copies) decodes the same pixels as OpenCV 16 % faster here (1.54 against 1.83 ms
a 780x582 frame); OpenCV takes what simplejpeg refuses (a grey or CMYK JPEG, damage)."""

from __future__ import annotations

import itertools
from collections import deque
from collections.abc import Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor

import cv2
import numpy as np
import simplejpeg

__all__ = ["decode_jpeg", "decoded_frames"]


def decode_jpeg(jpeg: bytes) -> np.ndarray | None:
    """A colour JPEG as an (H,W,3) BGR uint8 image, or None when it does not decode
    (empty bytes included: a garbled message in a log)."""
    if not jpeg:
        return None
    try:
        fast: np.ndarray = simplejpeg.decode_jpeg(jpeg, colorspace="BGR")
        return fast
    except (ValueError, RuntimeError):
        pass
    try:
        image = cv2.imdecode(np.frombuffer(jpeg, dtype=np.uint8), cv2.IMREAD_COLOR)
    except cv2.error:
        return None
    return image if image is not None and image.ndim == 3 else None


def decoded_frames(
    jpegs: Sequence[bytes], order: np.ndarray, threads: int
) -> Iterator[np.ndarray | None]:
    """The frames ``order`` decoded, in order, at most ``2 * threads`` ahead."""
    with ThreadPoolExecutor(max_workers=max(1, threads)) as pool:
        pending: deque[Future[np.ndarray | None]] = deque()
        todo = iter(order.tolist())
        for j in itertools.islice(todo, 2 * max(1, threads)):
            pending.append(pool.submit(decode_jpeg, jpegs[j]))
        while pending:
            done = pending.popleft()
            for j in itertools.islice(todo, 1):
                pending.append(pool.submit(decode_jpeg, jpegs[j]))
            yield done.result()
