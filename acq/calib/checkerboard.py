"""The checkerboard of a calibration: its size (``--board COLSxROWSxSQUARE``), its inner
corners found in an image (OpenCV), and the size a board in the images seems to have when
the one given is not found (:func:`board_hint`)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from acq.errors import InputValueError

__all__ = ["BoardSpec", "board_hint", "board_size", "detect_corners", "parse_board"]


@dataclass(frozen=True)
class BoardSpec:
    """A checkerboard: inner corners along its rows (cols) and columns (rows), square m."""

    cols: int
    rows: int
    square: float

    def text(self) -> str:
        """As --board takes it: ``9x7x0.1``."""
        return f"{self.cols}x{self.rows}x{self.square:g}"

    def object_points(self) -> np.ndarray:
        """(cols*rows, 3) corner positions on the board, m, in OpenCV's detection order."""
        j, i = np.mgrid[0 : self.rows, 0 : self.cols]
        return np.stack([i.ravel(), j.ravel(), np.zeros(i.size)], axis=1) * self.square


def parse_board(text: str) -> BoardSpec:
    """``COLSxROWSxSQUARE`` (inner corners, square side in metres), e.g. ``8x6x0.117``."""
    parts = text.lower().split("x")
    try:
        if len(parts) != 3:
            raise ValueError
        cols, rows, square = int(parts[0]), int(parts[1]), float(parts[2])
    except ValueError:
        raise InputValueError(
            f"--board {text!r}: expected COLSxROWSxSQUARE, e.g. 8x6x0.117 "
            "(inner corners, square side in metres)"
        ) from None
    if cols < 2 or rows < 2 or not (square > 0 and math.isfinite(square)):
        raise InputValueError(f"--board {text!r}: at least 2x2 inner corners and a square > 0")
    return BoardSpec(cols, rows, square)


def detect_corners(
    gray: np.ndarray, board: BoardSpec, *, fast: bool = False
) -> npt.NDArray[np.float64] | None:
    """(cols*rows, 2) sub-pixel inner corners (OpenCV's order), or None if not found.
    ``fast``: OpenCV's quick check for a board first (an image without one costs
    milliseconds, not a second; it may miss a board a full search would find)."""
    img = np.clip(gray, 0, 255).astype(np.uint8)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    if fast:
        flags |= cv2.CALIB_CB_FAST_CHECK
    found, corners = cv2.findChessboardCorners(img, (board.cols, board.rows), flags=flags)
    if not found:
        return None
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
    refined = cv2.cornerSubPix(img, corners, (5, 5), (-1, -1), crit)
    return np.asarray(refined, dtype=np.float64).reshape(-1, 2)


def board_size(grays: Sequence[np.ndarray]) -> tuple[int, int] | None:
    """The size (cols, rows; cols >= rows, inner corners) the checkerboard in ``grays``
    seems to have, or None: OpenCV's sector-based detector, let find a board larger
    than the 3x3 it is asked for, sees part of it in each image (where the lens cuts or
    bends it); the largest along each side over the images (~0.1-0.8 s an image)."""
    sizes: list[tuple[int, int]] = []
    for g in grays:
        img = np.clip(g, 0, 255).astype(np.uint8)
        found, _, meta = cv2.findChessboardCornersSBWithMeta(img, (3, 3), flags=cv2.CALIB_CB_LARGER)
        if found and meta is not None:
            rows, cols = meta.shape[:2]
            sizes.append((max(rows, cols), min(rows, cols)))
    if not sizes:
        return None
    return max(c for c, _ in sizes), max(r for _, r in sizes)


def board_hint(
    grays: Sequence[np.ndarray],
    board: BoardSpec,
    find: Callable[[np.ndarray, BoardSpec], object] | None = None,
) -> str:
    """ "; the images show a board of 9x7 inner corners (not squares): try --board 9x7x0.1"
    when :func:`board_size` is not ``board``'s (either way round) and ``find`` (default
    :func:`detect_corners`; None: not found) finds a board of that size in one of
    ``grays``, else "". The square's side stays ``board``'s."""
    size = board_size(grays)
    if size is None or size == (max(board.cols, board.rows), min(board.cols, board.rows)):
        return ""
    c, r = size if board.cols >= board.rows else size[::-1]
    spec = BoardSpec(c, r, board.square)
    look = find or (lambda g, b: detect_corners(g, b, fast=True))
    if not any(look(g, spec) is not None for g in grays):
        return ""
    return (
        f"; the images show a board of {c}x{r} inner corners (not squares): try --board "
        f"{spec.text()}"
    )
