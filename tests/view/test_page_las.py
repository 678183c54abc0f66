"""LAS and LAZ clouds on acq view's page in headless Chromium (tests/browser.py): drawn in
their own colours far from the origin (a CRS's coordinates), a subsampled cloud said so
in its layer's line."""

from __future__ import annotations

from pathlib import Path

from acq.view.server import ViewServer
from tests.browser import Browser
from tests.view.layer_files import las_cloud
from tests.view.test_page import BACKGROUND, WALL, _share, _show

FAR = (431_000.0, 4_582_000.0, 12.0)


def test_a_las_cloud_is_drawn_in_its_own_colours(browser: Browser, tmp_path: Path) -> None:
    path, _, _ = las_cloud(tmp_path / "wall.las", n=40_000, at=FAR, rgb=WALL)
    with ViewServer([path]) as server:
        image = _show(browser, server)
        line = browser.evaluate("document.querySelector('#layers label').textContent")
    assert _share(image, WALL, 4) > 0.05, "the cloud's colour is not on the screen"
    assert _share(image, BACKGROUND, 4) > 0.2
    assert line.strip() == "wall.las cloud, 40,000 points"


def test_a_subsampled_laz_cloud_says_how_many_points_it_shows(
    browser: Browser, tmp_path: Path
) -> None:
    path, _, _ = las_cloud(tmp_path / "wall.laz", n=30_000, at=FAR, rgb=WALL)
    with ViewServer([path], max_points=10_000) as server:
        image = _show(browser, server)
        line = browser.evaluate("document.querySelector('#layers label').textContent")
        drawn = browser.evaluate("document.querySelectorAll('#layers label').length")
    assert _share(image, WALL, 4) > 0.01
    assert drawn == 1 and line.strip() == "wall.laz cloud, 10,000 of 30,000 points"
