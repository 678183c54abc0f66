"""The distance tool of `acq view`'s page in headless Chromium (tests/browser.py): in
measure mode two clicks on a mesh 1000 km east (a CRS's coordinates) give the distance and
both points in the file's frame within 1 cm, a click near a cloud's point takes that point,
a click on the background, on a hidden layer or outside measure mode, or a drag (an orbit),
places nothing, Esc clears."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from acq.cloud.ply import PlyStream
from acq.view.server import ViewServer
from tests.browser import Browser
from tests.view.test_page import READY, ROAD, _road

EAST = np.array([1_000_000.0, 5_000_000.0, 0.0])  # the quad's corner, m
# two points on the quad, 8.544 m apart
A = EAST + np.array([1.5, -0.5, 0.0])
B = EAST + np.array([9.5, -3.5, 0.0])
CM = 0.01
MARKER = (255, 212, 0)  # the markers' colour (RGB)


def _quad(path: Path) -> Path:
    """A 10 x 4 m quad on the ground, as `acq mesh` writes it (.glb or .ply by the
    suffix), its corner at EAST, spanning +x 10 m and -y 4 m."""
    return _road(path, ROAD, at=(EAST[0], EAST[1]))


def _grid(path: Path) -> tuple[Path, np.ndarray]:
    """A cloud of 5 x 3 points 2 m apart on a wall at EAST, as `acq colorize` writes it."""
    x, z = np.meshgrid(np.arange(5) * 2.0, np.arange(3) * 2.0)
    xyz = np.stack([x.ravel(), np.zeros(x.size), z.ravel()], axis=1) + EAST
    n = len(xyz)
    out = PlyStream(path, ["frame world"], ["left"])
    out.write(
        xyz, np.full((n, 3), 200, np.uint8), np.linspace(0, 1, n), np.ones(n, np.float32),
        np.zeros(n, np.int32), np.ones(n, bool), np.zeros(n, np.uint8), np.zeros(n, np.int32),
    )  # fmt: skip
    out.close()
    return path, xyz


def _open(browser: Browser, server: ViewServer) -> None:
    browser.open(server.url)
    browser.wait_for(READY, timeout_s=60)
    assert browser.evaluate("window.acqError ?? null") is None
    browser.evaluate("document.getElementById('measure').click()")  # measure mode on


def _click_at(browser: Browser, xyz: np.ndarray, shift_px: float = 0.0) -> None:
    x, y = browser.evaluate(f"window.acqProject({[float(v) for v in xyz]})")
    browser.click(x + shift_px, y)


def _marker_share(image: np.ndarray, x: float, y: float) -> float:
    """The share of the 5 x 5 pixels about (x, y) in the markers' colour."""
    block = image[round(y) - 2 : round(y) + 3, round(x) - 2 : round(x) + 3].astype(np.int32)
    return float((np.abs(block - MARKER) <= 8).all(axis=2).mean())


def _readout(browser: Browser) -> str:
    return str(browser.evaluate("document.getElementById('measured').textContent"))


@pytest.mark.parametrize("suffix", [".glb", ".ply"])
def test_two_clicks_on_a_mesh_far_east_give_the_distance_and_the_file_s_coordinates(
    browser: Browser, tmp_path: Path, suffix: str
) -> None:
    with ViewServer([_quad(tmp_path / f"quad{suffix}")]) as server:
        _open(browser, server)
        _click_at(browser, A)
        one = browser.wait_for("window.acqMeasured")
        _click_at(browser, B)
        measured = browser.wait_for("window.acqMeasured?.distance && window.acqMeasured")
        shown = _readout(browser)
        pixels = [browser.evaluate(f"window.acqProject({p.tolist()})") for p in (A, B)]
        marked = browser.screenshot()
        browser.evaluate("window.dispatchEvent(new KeyboardEvent('keydown', {key: 'Escape'}))")
        cleared = browser.screenshot()
    # the markers on the screen where the points are drawn, gone once cleared
    for x, y in pixels:
        assert _marker_share(marked, x, y) > 0.5 and _marker_share(cleared, x, y) == 0
    assert len(one["points"]) == 1 and one["distance"] is None
    a, b = np.array(measured["points"])
    assert np.abs(a - A).max() < CM and np.abs(b - B).max() < CM, (a - A, b - B)
    truth = float(np.linalg.norm(B - A))
    assert abs(measured["distance"] - truth) < CM
    # the panel: the distance to the millimetre, each point in the file's frame
    assert f"distance {measured['distance']:.3f} m" in shown
    assert f"A: local frame x {a[0]:.3f} y {a[1]:.3f} z {a[2]:.3f}" in shown
    assert shown.count("1000") == 2 and browser.errors == [], (shown, browser.console)


def test_a_click_near_a_cloud_s_point_takes_that_point(browser: Browser, tmp_path: Path) -> None:
    path, xyz = _grid(tmp_path / "grid.ply")
    with ViewServer([path]) as server:
        _open(browser, server)
        _click_at(browser, (xyz[6] + xyz[7]) / 2)  # 1 m from either (tens of pixels)
        assert browser.evaluate("window.acqMeasured") is None
        _click_at(browser, xyz[6], shift_px=3)  # 3 px beside it: within the tool's reach
        _click_at(browser, xyz[13], shift_px=-3)
        measured = browser.wait_for("window.acqMeasured?.distance && window.acqMeasured")
    # the cloud's own points, not where the ray passed by them
    assert np.abs(np.array(measured["points"]) - xyz[[6, 13]]).max() < 1e-6
    assert abs(measured["distance"] - np.linalg.norm(xyz[13] - xyz[6])) < 1e-6


def test_the_background_or_a_click_outside_measure_mode_places_nothing_and_esc_clears(
    browser: Browser, tmp_path: Path
) -> None:
    with ViewServer([_quad(tmp_path / "quad.ply")]) as server:
        _open(browser, server)
        browser.click(790, 590)  # a corner of the page, far from the quad: the background
        assert browser.evaluate("window.acqMeasured") is None
        x, y = browser.evaluate(f"window.acqProject({A.tolist()})")
        browser.drag(x, y, x + 8, y + 2)  # on the quad, but an orbit: no point placed
        assert browser.evaluate("window.acqMeasured") is None
        _click_at(browser, A)
        browser.click(790, 590)
        _click_at(browser, B)
        measured = browser.wait_for("window.acqMeasured?.distance && window.acqMeasured")
        assert abs(measured["distance"] - np.linalg.norm(B - A)) < CM  # A and B, no third
        browser.evaluate("window.dispatchEvent(new KeyboardEvent('keydown', {key: 'Escape'}))")
        assert browser.evaluate("window.acqMeasured") is None
        assert "distance" not in _readout(browser)
        # the toggle off: a click on the quad is the orbit's, not a measurement
        browser.evaluate("document.getElementById('measure').click()")
        _click_at(browser, A)
        assert browser.evaluate("window.acqMeasured") is None and _readout(browser) == ""
        # a third click starts a new measurement
        browser.evaluate("document.getElementById('measure').click()")
        for point in (A, B, A):
            _click_at(browser, point)
        again = browser.wait_for("window.acqMeasured")
        assert len(again["points"]) == 1 and np.abs(np.array(again["points"][0]) - A).max() < CM
        # a hidden layer is not measured on
        browser.evaluate("document.querySelector('#layers input').click()")
        browser.evaluate("window.dispatchEvent(new KeyboardEvent('keydown', {key: 'Escape'}))")
        _click_at(browser, A)
        assert browser.evaluate("window.acqMeasured") is None
        assert browser.errors == [], browser.console
