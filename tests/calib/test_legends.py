"""The overlays a user looks at say what their marks mean: `acq calibrate validate -o`'s
and `acq sim render`'s carry a legend, a swatch of each mark's colour beside its words."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from acq.calib.validate import validate
from acq.log import drive_log
from acq.sim.render import _MAGENTA, draw_overlay
from acq.sim.validation_log import write_validation_log


def _swatch(img: np.ndarray, colour: tuple[int, int, int], side: int = 10) -> bool:
    """Whether ``img`` holds a ``side`` x ``side`` square of exactly ``colour`` (a point
    or a guide line is never that big)."""
    mask = np.all(img == np.array(colour, np.uint8), axis=2).astype(np.uint8)
    return bool(cv2.erode(mask, np.ones((side, side), np.uint8)).any())


def _text_beside(img: np.ndarray, colour: tuple[int, int, int]) -> bool:
    """White text to the right of the swatch of ``colour``."""
    mask = np.all(img == np.array(colour, np.uint8), axis=2).astype(np.uint8)
    ys, xs = np.nonzero(cv2.erode(mask, np.ones((10, 10), np.uint8)))
    y, x = int(ys[0]), int(xs.max())
    strip = img[max(y - 8, 0) : y + 12, x + 8 : x + 200]
    return int(np.all(strip > 200, axis=2).sum()) > 20


def test_the_validation_overlay_has_a_legend(tmp_path: Path) -> None:
    log = write_validation_log(tmp_path / "log", duration_s=0.3)
    png = tmp_path / "overlay.png"
    res = validate(drive_log.read_log(log.files), log.calibration.camera(), overlay=png)
    assert res.points > 0
    img = cv2.imread(str(png))
    assert img is not None
    for colour in ((0, 255, 0), (0, 0, 255)):  # on the right colour, on another
        assert _swatch(img, colour), colour
        assert _text_beside(img, colour), colour


def test_the_render_overlay_has_a_legend() -> None:
    zoom = 3
    image = np.full((480, 640, 3), 90, np.uint8)
    v = np.linspace(100, 400, 200)
    uv = np.stack([320 + 0.1 * v, v], axis=1)
    colours = np.tile(np.array([[30, 160, 220]], np.uint8), (len(uv), 1))
    out = draw_overlay(image, uv, colours, zoom=zoom)
    assert out.shape == (480, 640 + 480 // zoom * zoom, 3)
    assert _swatch(out[:, :640], _MAGENTA) and _text_beside(out[:, :640], _MAGENTA)
    panel = out[:, 640:]
    assert int(np.all(panel > 200, axis=2).sum()) > 50  # the zoom's caption
