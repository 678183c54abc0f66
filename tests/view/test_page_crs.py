"""The CRS on acq view's page in headless Chromium (tests/browser.py): the distance tool
gives each point in its layer's CRS (easting, northing, height) or local frame, the panel
says when layers disagree; a view in a projected CRS has a scale bar whose length is its
label at the view's scale and a north arrow that turns with the view; a local one has
neither."""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from acq.view.server import ViewServer
from tests.browser import Browser
from tests.view.layer_files import las_cloud
from tests.view.test_page import BACKGROUND, READY, WALL, _wall
from tests.view.test_page_distance import EAST, _click_at, _readout

LIGHT = (0xE8, 0xEA, 0xED)  # the overlays' colour


def _las_grid(path: Path, crs: str | None) -> tuple[Path, np.ndarray]:
    """A wall of 5 x 3 points 2 m apart 1,000 km east, as `acq colorize --crs` writes
    it to LAS (``crs`` None: as in its local frame)."""
    x, z = np.meshgrid(np.arange(5) * 2.0, np.arange(3) * 2.0)
    xyz = np.stack([x.ravel(), np.zeros(x.size), z.ravel()], axis=1) + EAST
    path, xyz, _ = las_cloud(path, xyz=xyz, crs=crs, rgb=(200, 200, 200))
    return path, xyz


@contextmanager
def _projected(browser: Browser, tmp_path: Path) -> Iterator[None]:
    """The page open on the wall of :func:`_las_grid` in EPSG:25831."""
    path, _ = _las_grid(tmp_path / "wall.las", "EPSG:25831")
    with ViewServer([path]) as server:
        _open(browser, server)
        yield


def _open(browser: Browser, server: ViewServer) -> None:
    browser.open(server.url)
    browser.wait_for(READY, timeout_s=60)
    assert browser.evaluate("window.acqError ?? null") is None, browser.console


def _crs_panel(browser: Browser) -> list[tuple[str, str]]:
    """The panel's CRS lines: (text, class) each."""
    return [
        (str(t), str(c))
        for t, c in browser.evaluate(
            "[...document.querySelectorAll('#crs div')].map((d) => [d.textContent, d.className])"
        )
    ]


def test_the_distance_tool_gives_each_point_in_its_layer_s_crs(
    browser: Browser, tmp_path: Path
) -> None:
    path, xyz = _las_grid(tmp_path / "wall.las", "EPSG:25831")
    with ViewServer([path]) as server:
        _open(browser, server)
        browser.evaluate("document.getElementById('measure').click()")
        _click_at(browser, xyz[6], shift_px=2)
        _click_at(browser, xyz[13], shift_px=-2)
        measured = browser.wait_for("window.acqMeasured?.distance && window.acqMeasured")
        shown = _readout(browser)
        panel = _crs_panel(browser)
    a, b = xyz[6], xyz[13]
    assert np.abs(np.array(measured["points"]) - xyz[[6, 13]]).max() < 0.0006  # the file's mm
    assert measured["labels"] == [
        f"EPSG:25831 E {p[0]:.3f} N {p[1]:.3f} h {p[2]:.3f}" for p in (a, b)
    ]
    assert f"A: EPSG:25831 E {a[0]:.3f} N {a[1]:.3f} h {a[2]:.3f}" in shown.splitlines()
    assert f"B: EPSG:25831 E {b[0]:.3f} N {b[1]:.3f} h {b[2]:.3f}" in shown.splitlines()
    assert panel == [("CRS EPSG:25831", "")] and browser.errors == [], browser.console


def test_layers_that_disagree_on_their_crs_are_named_and_each_point_keeps_its_own(
    browser: Browser, tmp_path: Path
) -> None:
    utm31, xyz = _las_grid(tmp_path / "utm31.las", "EPSG:25831")
    utm32, _ = _las_grid(tmp_path / "utm32.las", "EPSG:25832")
    local, _ = _las_grid(tmp_path / "local.las", None)
    bad = tmp_path / "bad.las"  # its WKT's first keyword misspelt: no CRS pyproj can read
    bad.write_bytes(utm31.read_bytes().replace(b"PROJCS[", b"PROJXX[", 1))
    with ViewServer([utm31, utm32, local, bad]) as server:
        _open(browser, server)
        panel = _crs_panel(browser)
        # only the local layer shown, then only the one whose CRS cannot be read: each
        # point labelled as in its own file
        browser.evaluate("[...document.querySelectorAll('#layers input')]"
                         ".filter((_, k) => k !== 2).forEach((box) => box.click())")  # fmt: skip
        browser.evaluate("document.getElementById('measure').click()")
        _click_at(browser, xyz[6], shift_px=2)
        local_label = browser.wait_for("window.acqMeasured?.labels[0]")
        browser.evaluate("[...document.querySelectorAll('#layers input')]"
                         ".filter((_, k) => k >= 2).forEach((box) => box.click())")  # fmt: skip
        browser.evaluate("window.dispatchEvent(new KeyboardEvent('keydown', {key: 'Escape'}))")
        _click_at(browser, xyz[6], shift_px=2)
        bad_label = browser.wait_for("window.acqMeasured?.labels[0]")
    assert panel[:2] == [
        ("the layers disagree on their CRS: utm31.las EPSG:25831, utm32.las EPSG:25832; "
         "each point is given in its own layer's", "warning"),
        ("no CRS in local.las: drawn in its own coordinates", ""),
    ]  # fmt: skip
    assert len(panel) == 3 and panel[2][1] == "warning"
    assert panel[2][0].startswith("bad.las: its CRS cannot be read (") and "PROJXX" in panel[2][0]
    p = xyz[6]
    assert local_label == f"local frame x {p[0]:.3f} y {p[1]:.3f} z {p[2]:.3f}"
    assert bad_label == f"unread CRS x {p[0]:.3f} y {p[1]:.3f} z {p[2]:.3f}"
    assert browser.errors == [], browser.console


def _overlays(browser: Browser) -> dict[str, float] | None:
    """What the page's overlays draw: the scale bar's width (px, on the screen), its
    label's metres, the arrow's rotation (degrees clockwise, from its CSS transform)."""
    found = browser.evaluate("""(() => {
        const bar = document.querySelector('#scale-bar .bar');
        const arrow = document.getElementById('north-arrow');
        if (!bar || !arrow) return null;
        const m = new DOMMatrix(getComputedStyle(arrow).transform);
        return {px: bar.getBoundingClientRect().width,
                label: document.querySelector('#scale-bar .label').textContent,
                deg: Math.atan2(m.b, m.a) * 180 / Math.PI,
                perPixel: window.acqOverlays.metresPerPixel};
    })()""")
    if found is None:
        return None
    number, unit = found["label"].split()
    scale = {"km": 1000.0, "m": 1.0, "cm": 0.01, "mm": 0.001}[unit]
    return {**found, "metres": float(number) * scale}


def _screen_angle(browser: Browser, step: list[float]) -> float:
    """The direction on the screen (degrees clockwise from up) of ``step`` (m) from the
    orbit's target, from the page's own projection of both points."""
    target = np.array(browser.evaluate("window.acqTarget()"))
    x0, y0 = browser.evaluate(f"window.acqProject({target.tolist()})")
    x1, y1 = browser.evaluate(f"window.acqProject({(target + step).tolist()})")
    return math.degrees(math.atan2(x1 - x0, -(y1 - y0)))


def _turned(a: float, b: float) -> float:
    """b - a in degrees, in (-180, 180]."""
    return -((a - b + 180) % 360 - 180)


def test_a_projected_view_has_a_scale_bar_and_a_north_arrow_a_local_one_neither(
    browser: Browser, tmp_path: Path
) -> None:
    with _projected(browser, tmp_path):
        drawn = _overlays(browser)
        image = browser.screenshot()
        rect = browser.evaluate("document.querySelector('#scale-bar .bar')"
                                ".getBoundingClientRect().toJSON()")  # fmt: skip
        arrow = browser.evaluate("document.getElementById('north-arrow')"
                                 ".getBoundingClientRect().toJSON()")  # fmt: skip
    assert drawn is not None and 30 < drawn["px"] <= 120
    # the bar's bottom line and the arrow on the screen in the overlays' colour
    bottom = image[round(rect["bottom"]) - 2, round(rect["left"]) + 3 : round(rect["right"]) - 3]
    assert (np.abs(bottom.astype(int) - LIGHT) <= 8).all(axis=1).mean() > 0.9
    box = image[
        round(arrow["top"]) : round(arrow["bottom"]), round(arrow["left"]) : round(arrow["right"])
    ]
    assert (np.abs(box.astype(int) - LIGHT) <= 8).all(axis=2).mean() > 0.015
    for local in (_wall(tmp_path / "local.ply", WALL), _las_grid(tmp_path / "l.las", None)[0]):
        with ViewServer([local]) as server:
            _open(browser, server)
            assert _overlays(browser) is None
            assert (
                browser.evaluate("document.querySelectorAll('#scale-bar, #north-arrow').length")
                == 0
            )
            image = browser.screenshot()
        assert (np.abs(image[8:60, -60:-8].astype(int) - BACKGROUND) <= 4).all()


def test_the_north_arrow_turns_with_the_view_and_points_to_grid_north(
    browser: Browser, tmp_path: Path
) -> None:
    with _projected(browser, tmp_path):
        first = _overlays(browser)
        browser.evaluate("window.acqTurn(90)")
        turned = _overlays(browser)
        # looking due north (the page frames from the south-east: 45 degrees back), then west
        browser.evaluate("window.acqTurn(-135)")
        north = (_overlays(browser), _screen_angle(browser, [0.0, 1.0, 0.0]))
        browser.evaluate("window.acqTurn(90)")
        west = (_overlays(browser), _screen_angle(browser, [0.0, 1.0, 0.0]))
        assert browser.errors == [], browser.console
    assert first is not None and turned is not None
    # the camera turned 90 degrees counter-clockwise about z: north 90 degrees clockwise
    assert _turned(first["deg"], turned["deg"]) == pytest.approx(90, abs=0.5)
    for drawn, on_screen in (north, west):
        assert drawn is not None
        assert _turned(on_screen, drawn["deg"]) == pytest.approx(0, abs=0.5), (drawn, on_screen)
    assert north[0]["deg"] == pytest.approx(0, abs=0.5)  # type: ignore[index]
    assert west[0]["deg"] == pytest.approx(90, abs=0.5)  # type: ignore[index]


def test_the_scale_bar_is_its_label_at_the_view_s_scale_and_follows_the_zoom(
    browser: Browser, tmp_path: Path
) -> None:
    with _projected(browser, tmp_path):
        browser.evaluate("window.acqTurn(-45)")  # looking due north: east is the screen's x
        seen = []
        for _ in range(3):
            drawn = _overlays(browser)
            assert drawn is not None
            target = np.array(browser.evaluate("window.acqTarget()"))
            x0, _ = browser.evaluate(f"window.acqProject({target.tolist()})")
            east = target + np.array([drawn["metres"], 0.0, 0.0])
            x1, _ = browser.evaluate(f"window.acqProject({east.tolist()})")
            seen.append((drawn, x1 - x0))
            browser.evaluate(  # the wheel, as a user's: the view closes in on the target
                "document.querySelector('#view canvas').dispatchEvent(new WheelEvent('wheel', "
                "{deltaY: -600, clientX: 400, clientY: 300, bubbles: true, cancelable: true}))"
            )
        assert browser.errors == [], browser.console
    for drawn, projected_px in seen:
        # the bar's pixels times the page's metres per pixel, and the label's metres drawn
        # by the page's own projection at the target: the bar's length, within 3 %
        assert drawn["px"] * drawn["perPixel"] == pytest.approx(drawn["metres"], rel=0.03)
        assert drawn["px"] == pytest.approx(projected_px, rel=0.03), (drawn, projected_px)
        assert drawn["metres"] in {k * 10.0**e for k in (1, 2, 5) for e in range(-3, 5)}
    assert seen[-1][0]["metres"] < seen[0][0]["metres"]  # zoomed in: a shorter round length
