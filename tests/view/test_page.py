"""The page of `acq view` in headless Chromium (tests/browser.py): each kind of layer drawn
in its own colours with no console message, and a layer that went missing said so."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from acq.cloud.ply import PlyStream
from acq.mesh import files
from acq.view.server import ViewServer
from tests.browser import Browser

READY = "window.acqReady === true || window.acqError !== undefined"
WALL = (200, 60, 40)  # a cloud's colour (RGB)
ROAD = (40, 120, 200)  # a mesh's colour
BACKGROUND = (0x20, 0x21, 0x24)  # the page's


def _wall(path: Path, rgb: tuple[int, int, int], n: int = 40_000) -> Path:
    """A PLY cloud of ``n`` points on a 10 x 4 m wall 1 km east, 5 km north (a CRS's
    large coordinates), every point of colour ``rgb``, as `acq colorize` writes it."""
    rng = np.random.default_rng(1)
    xyz = np.stack([rng.uniform(0, 10, n), np.zeros(n), rng.uniform(0, 4, n)], axis=1)
    xyz += [1000.0, 5000.0, 0.0]
    out = PlyStream(path, ["frame world"], ["left"])
    out.write(
        xyz, np.tile(np.array(rgb, np.uint8), (n, 1)), np.linspace(0, 1, n),
        np.ones(n, np.float32), np.zeros(n, np.int32), np.ones(n, bool), np.zeros(n, np.uint8),
        np.zeros(n, np.int32),
    )  # fmt: skip
    out.close()
    return path


def _road(path: Path, rgb: tuple[int, int, int], at: tuple[float, float] = (0.0, 0.0)) -> Path:
    """A mesh (.glb or .ply by the suffix) of a 10 x 4 m quad of colour ``rgb`` on the
    ground, its corner at ``at`` (x, y) m."""
    xyz = np.array([[0, 0, 0], [10, 0, 0], [0, -4, 0], [10, -4, 0]], float)
    xyz += np.array([at[0], at[1], 0.0])
    faces = np.array([[0, 1, 2], [1, 3, 2]])
    files.write(path, xyz, np.tile(np.array(rgb, np.uint8), (4, 1)), faces)
    return path


def _share(image: np.ndarray, rgb: tuple[int, int, int], tolerance: int = 24) -> float:
    """The share of ``image``'s pixels within ``tolerance`` of ``rgb`` in every channel."""
    near = np.abs(image.astype(np.int32) - np.array(rgb)) <= tolerance
    return float(near.all(axis=2).mean())


def _show(browser: Browser, server: ViewServer) -> np.ndarray:
    browser.open(server.url)
    browser.wait_for(READY, timeout_s=60)
    assert browser.evaluate("window.acqError ?? null") is None
    assert browser.errors == [], browser.console
    return browser.screenshot()


def test_a_cloud_is_drawn_in_its_own_colours(browser: Browser, tmp_path: Path) -> None:
    with ViewServer([_wall(tmp_path / "wall.ply", WALL)]) as server:
        image = _show(browser, server)
    assert _share(image, WALL, 4) > 0.05, "the wall's colour is not on the screen"
    assert _share(image, BACKGROUND, 4) > 0.2
    assert browser.evaluate("document.querySelectorAll('#layers input').length") == 1
    # no drive: no trajectory to walk, no frames to show
    hidden = "document.getElementById('{}').closest('.control').hidden"
    assert browser.evaluate(hidden.format("walk")) is True
    assert browser.evaluate(hidden.format("show-frame")) is True


def test_meshes_of_both_kinds_are_drawn_in_their_own_colours(
    browser: Browser, tmp_path: Path
) -> None:
    # a PLY's colours are sRGB bytes; a glb's COLOR_0 linear (glTF), shown as sRGB
    for suffix in (".glb", ".ply"):
        with ViewServer([_road(tmp_path / f"road{suffix}", ROAD)]) as server:
            image = _show(browser, server)
        assert _share(image, ROAD, 4) > 0.05, f"{suffix}: the quad's colour is not on the screen"


def test_a_hidden_layer_leaves_the_other(browser: Browser, tmp_path: Path) -> None:
    road = _road(tmp_path / "road.ply", ROAD, at=(1000.0, 5000.0))  # at the wall's foot
    with ViewServer([_wall(tmp_path / "wall.ply", WALL), road]) as server:
        image = _show(browser, server)
        assert _share(image, WALL) > 0.01 and _share(image, ROAD) > 0.01
        browser.evaluate("document.querySelectorAll('#layers input')[0].click()")
        hidden = browser.screenshot()
    assert _share(hidden, WALL) < 0.001 and _share(hidden, ROAD) > 0.01


def test_a_layer_gone_after_the_start_is_named_on_the_page(
    browser: Browser, tmp_path: Path
) -> None:
    gone = _road(tmp_path / "gone.ply", ROAD)  # a mesh: served from its file when asked
    with ViewServer([gone]) as server:
        gone.unlink()
        browser.open(server.url)
        error = browser.wait_for("window.acqError", timeout_s=60)
        shown = browser.evaluate("document.getElementById('message').textContent")
    assert "gone.ply" in error and "gone.ply" in shown
