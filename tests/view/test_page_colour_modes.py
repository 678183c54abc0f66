"""The colour modes of acq view's page in headless Chromium (tests/browser.py): a cloud
written by acq's PLY and LAS writers whose left half and right half differ in every
attribute shows, in each mode, the mode's two colours in the right halves of the screen
(and the legend's, where the legend has swatches); a foreign cloud of x y z only has its
other modes disabled and says it has no colours."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from acq.cloud.las import LasStream
from acq.cloud.ply import PlyStream
from acq.view.server import ViewServer
from tests.browser import Browser
from tests.view.test_page import BACKGROUND, READY, ROAD, WALL

FAR = (431_000.0, 4_582_000.0, 12.0)
UTC0 = 1_764_000_000.0
# the ramps' ends, as the page's colour_modes.js defines them (sRGB)
VIRIDIS_ENDS = ((68, 1, 84), (253, 231, 37))
# how many requests for URLs holding a string the page made (Resource Timing)
FETCHED = "performance.getEntriesByType('resource').filter((e) => e.name.includes(%r)).length"
GREY_ENDS = ((64, 64, 64), (255, 255, 255))


def _halves(path: Path, n: int = 30_000) -> Path:
    """A 10 x 4 m wall of ``n`` points far from the origin whose left half (x < 5 m, the
    left of the page's first view) and right half differ in every attribute: colour WALL
    / ROAD, intensity 0 / 1000, time 0 / 100 s, scan 0 / 1, camera 0 / 1, coloured 1 / 0."""
    rng = np.random.default_rng(3)
    x = np.sort(rng.uniform(0, 10, n))
    xyz = np.stack([x, np.zeros(n), rng.uniform(0, 4, n)], axis=1) + np.array(FAR)
    right = x >= 5
    rgb = np.where(right[:, None], np.array(ROAD, np.uint8), np.array(WALL, np.uint8))
    columns = (
        xyz, rgb.astype(np.uint8), UTC0 + 100.0 * right, (1000.0 * right).astype(np.float32),
        right.astype(np.int32), ~right, right.astype(np.uint8), np.zeros(n, np.int32),
    )  # fmt: skip
    if path.suffix == ".ply":
        out: PlyStream | LasStream = PlyStream(path, ["frame world"], ["front", "rear"])
    else:
        out = LasStream(path, crs="EPSG:25831", cameras=["front", "rear"])
    out.write(*columns)
    out.close()
    return path


def _select(browser: Browser, mode: str) -> np.ndarray:
    """The screen with the colour mode ``mode`` chosen, the panel hidden (its white text
    is no point's)."""
    _choose(browser, mode)
    browser.wait_for(f"window.acqColourMode === '{mode}'", timeout_s=30)
    browser.evaluate("document.getElementById('panel').style.visibility = 'hidden'")
    image = browser.screenshot()
    browser.evaluate("document.getElementById('panel').style.visibility = ''")
    return image


def _choose(browser: Browser, mode: str) -> str:
    """The colour mode ``mode`` chosen as a user does; the select's text right after."""
    text = browser.evaluate(
        f"(() => {{ const c = document.getElementById('colour-mode'); c.value = '{mode}';"
        " c.dispatchEvent(new Event('change')); return c.selectedOptions[0].textContent; })()"
    )
    assert isinstance(text, str)
    return text


def _columns(image: np.ndarray, rgb: tuple[int, int, int], tolerance: int = 6) -> np.ndarray:
    near = (np.abs(image.astype(np.int32) - np.array(rgb)) <= tolerance).all(axis=2)
    return np.nonzero(near)[1]


def _left_and_right(image: np.ndarray, left: tuple[int, ...], right: tuple[int, ...]) -> None:
    a, b = _columns(image, left[:3]), _columns(image, right[:3])  # type: ignore[arg-type]
    assert len(a) > 300 and len(b) > 300, (left, len(a), right, len(b))
    assert np.median(a) + 40 < np.median(b), (left, np.median(a), right, np.median(b))


def _swatches(browser: Browser) -> list[tuple[str, tuple[int, ...]]]:
    """The legend's swatches: their text and colour."""
    items = browser.evaluate(
        "[...document.querySelectorAll('#legend .swatch')].map((s) => "
        "[s.textContent, getComputedStyle(s.querySelector('i')).backgroundColor])"
    )
    return [(text, tuple(int(v) for v in colour[4:-1].split(","))) for text, colour in items]


@pytest.mark.parametrize("name", ["halves.ply", "halves.las"])
def test_each_colour_mode_shows_its_colours_on_the_right_halves(
    browser: Browser, tmp_path: Path, name: str
) -> None:
    with ViewServer([_halves(tmp_path / name)]) as server:
        browser.open(server.url)
        browser.wait_for(READY, timeout_s=60)
        assert browser.evaluate("window.acqError ?? null") is None
        options = browser.evaluate(
            "[...document.querySelectorAll('#colour-mode option')]"
            ".map((o) => [o.value, o.disabled])"
        )
        assert options == [
            [m, False] for m in ("rgb", "intensity", "time", "scan", "camera", "coloured")
        ]
        _left_and_right(_select(browser, "rgb"), WALL, ROAD)
        # the first frame had positions and colours only: the attributes come when a mode
        # first needs them (once: the other modes use them as they are)
        assert _choose(browser, "intensity") == "loading attributes…"
        _left_and_right(_select(browser, "intensity"), *GREY_ENDS)
        assert browser.evaluate(FETCHED % "attributes.bin") == 1
        assert browser.evaluate("document.getElementById('colour-mode').disabled") is False
        assert "2nd to 98th percentile" in browser.evaluate(
            "document.getElementById('legend').textContent"
        )
        _left_and_right(_select(browser, "time"), *VIRIDIS_ENDS)
        legend = browser.evaluate("document.getElementById('legend').textContent")
        assert "from 2025-11-24 16:00:00 UTC" in legend and "100.0 s" in legend, legend

        image = _select(browser, "coloured")
        swatches = _swatches(browser)
        assert [text for text, _ in swatches] == ["coloured", "not coloured"]
        _left_and_right(image, swatches[0][1], swatches[1][1])

        image = _select(browser, "camera")
        swatches = _swatches(browser)
        assert [text for text, _ in swatches] == ["front", "rear", "none"]
        _left_and_right(image, swatches[0][1], swatches[1][1])

        image = _select(browser, "scan")
        swatches = _swatches(browser)
        assert [text for text, _ in swatches][:2] == ["0", "1"]
        _left_and_right(image, swatches[0][1], swatches[1][1])
        assert browser.evaluate(FETCHED % "attributes.bin") == 1
        assert browser.errors == [], browser.console


def test_attributes_that_cannot_be_fetched_are_said_in_the_legend(
    browser: Browser, tmp_path: Path
) -> None:
    """The attributes' request fails (blocked in the browser: a network that drops it);
    the page says which layer's and why, draws it grey and asks again at the next choice."""
    with ViewServer([_halves(tmp_path / "halves.ply")]) as server:
        browser.open(server.url)
        browser.wait_for(READY, timeout_s=60)
        browser.block("*/attributes.bin")
        try:
            image = _select(browser, "intensity")
            legend = browser.evaluate("document.getElementById('legend').textContent")
            assert legend == ("halves.ply: its attributes could not be loaded (Failed to fetch)"), (
                legend
            )
            assert browser.evaluate("document.querySelector('#legend .error') !== null")
            assert len(_columns(image, GREY_ENDS[0])) == 0  # no ramp: grey
            assert len(_columns(image, (128, 128, 128))) > 300
        finally:
            browser.block()
        _left_and_right(_select(browser, "time"), *VIRIDIS_ENDS)  # asked again, and come
        assert "could not" not in browser.evaluate("document.getElementById('legend').textContent")


def test_a_cloud_of_x_y_z_only_has_rgb_alone_and_says_so(browser: Browser, tmp_path: Path) -> None:
    from plyfile import PlyData, PlyElement

    rng = np.random.default_rng(0)
    xyz = np.zeros(20_000, [("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    xyz["x"], xyz["z"] = rng.uniform(0, 10, 20_000), rng.uniform(0, 4, 20_000)
    path = tmp_path / "bare.ply"
    PlyData([PlyElement.describe(xyz, "vertex")]).write(str(path))
    with ViewServer([path]) as server:
        browser.open(server.url)
        browser.wait_for(READY, timeout_s=60)
        options = browser.evaluate(
            "[...document.querySelectorAll('#colour-mode option')].map((o) => o.disabled)"
        )
        assert options == [False, True, True, True, True, True]
        assert browser.evaluate("document.getElementById('legend').textContent") == (
            "bare.ply: no colours"
        )
        image = _select(browser, "rgb")
    assert len(_columns(image, (208, 208, 208))) > 1000  # NO_RGB of colour_modes.js
    assert len(_columns(image, BACKGROUND)) > 0.2 * image.shape[0] * image.shape[1]


# a second Points object of the layer's points added to its object, as a finer level of
# detail is: coloured in the mode shown by applyColourMode, and by each mode chosen after
ADD_CHILD = """(async () => {
  const { parsePoints, pointsObject } = await import('/static/points.js');
  const { applyColourMode } = await import('/static/colour_modes.js');
  const root = window.acqScene.getObjectByName('halves.ply');
  const buffer = await (await fetch('/data/0/points.bin')).arrayBuffer();
  const child = pointsObject(parsePoints(buffer), 2, '/data/0/attributes.bin');
  child.position.set(0, 0, 0);  // its origin is its parent's
  root.add(child);
  await applyColourMode(child);  // its attributes fetched, then coloured
  window.acqChild = child;
})()"""
SAME = """(() => {
  const a = window.acqScene.getObjectByName('halves.ply').geometry.getAttribute('color').array;
  const b = window.acqChild.geometry.getAttribute('color').array;
  return a.length === b.length && a.every((v, i) => v === b[i]) && [b[0], b[1], b[2]];
})()"""


def test_a_points_object_added_to_a_layer_takes_its_colour_mode(
    browser: Browser, tmp_path: Path
) -> None:
    with ViewServer([_halves(tmp_path / "halves.ply")]) as server:
        browser.open(server.url)
        browser.wait_for(READY, timeout_s=60)
        _select(browser, "coloured")
        browser.evaluate(ADD_CHILD)
        coloured = browser.evaluate(SAME)
        _select(browser, "camera")
        camera = browser.evaluate(SAME)
        assert browser.errors == [], browser.console
    assert coloured and camera and coloured != camera, (coloured, camera)
    # the left half's first point: the coloured colour (46, 204, 64) in linear terms, then
    # camera 0's (78, 121, 167): green over red, then blue over red
    assert coloured[1] > coloured[0] and camera[2] > camera[0], (coloured, camera)
