"""Finer points as the view closes in, in headless Chromium (tests/browser.py): a drive's
cloud over --max-points, the view set onto one end, loads that end's chunks at full
density and none of the far end's, and more points are drawn there."""

from __future__ import annotations

import json
import re
import urllib.request
from pathlib import Path

import numpy as np

from acq.cloud.copc import CopcStream
from acq.view.server import ViewServer
from tests.browser import Browser
from tests.view.test_page import BACKGROUND, READY, WALL

SETTLED = "window.acqLod !== undefined && window.acqLod.idle && window.acqLod.updates > {n}"


def _street(n: int) -> np.ndarray:
    """``n`` points along a 200 m street (x 0-200 m, y -4-4 m, z 0-4 m) in time order."""
    rng = np.random.default_rng(3)
    x = np.sort(rng.uniform(0, 200, n))
    return np.stack([x, rng.uniform(-4, 4, n), rng.uniform(0, 4, n)], axis=1)


def _drive(path: Path, n: int = 200_000) -> Path:
    """A LAZ cloud of the street's ``n`` points (:func:`_street`), every point of colour
    WALL; COPC as `acq colorize` writes it for a name ending .copc.laz."""
    import laspy

    xyz = _street(n)
    if path.name.endswith(".copc.laz"):
        out = CopcStream(path, cameras=["left"])
        out.write(
            xyz, np.tile(np.array(WALL, np.uint8), (n, 1)), np.linspace(0, 10, n),
            np.ones(n, np.float32), np.zeros(n, np.int32), np.ones(n, bool),
            np.zeros(n, np.uint8), np.zeros(n, np.int32),
        )  # fmt: skip
        out.close()
        return path
    header = laspy.LasHeader(point_format=7, version="1.4")
    header.scales, header.offsets = np.array([0.001] * 3), np.zeros(3)
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz.T
    las.red, las.green, las.blue = (np.full(n, c * 257, np.uint16) for c in WALL)
    las.write(path)
    return path


def _open(browser: Browser, url: str) -> None:
    browser.open(url)
    browser.wait_for(READY, timeout_s=60)
    assert browser.evaluate("window.acqError ?? null") is None
    browser.wait_for(SETTLED.format(n=0), timeout_s=30)


def _look_at_the_start(browser: Browser, x: float = 5) -> None:
    """The view from 15 m south of the street at ``x`` (m; its start), looking at it."""
    n = browser.evaluate("window.acqLod.updates")
    browser.evaluate(f"window.acqLod.look([{x}, -15, 4], [{x}, 0, 2])")
    browser.wait_for(SETTLED.format(n=n), timeout_s=60)


def _drawn(image: np.ndarray) -> int:
    """Pixels not of the background in a 100 x 100 square at the screen's centre."""
    h, w = image.shape[:2]
    square = image[h // 2 - 50 : h // 2 + 50, w // 2 - 50 : w // 2 + 50].astype(np.int32)
    return int((np.abs(square - np.array(BACKGROUND)).max(axis=2) > 8).sum())


def test_closing_in_on_one_end_loads_its_chunks_only(browser: Browser, tmp_path: Path) -> None:
    path = _drive(tmp_path / "drive.laz")
    with ViewServer([path], max_points=10_000, run_points=20_000) as server:
        assert server.wait(60)  # packed, its chunks known
        with urllib.request.urlopen(server.url + "data/0/lod.json", timeout=10) as r:
            chunks = json.load(r)["chunks"]
        assert len(chunks) == 10
        # a budget the subset fills: nothing more is loaded, the coarse view for comparison
        _open(browser, server.url + "?budget=10000")
        _look_at_the_start(browser)
        assert browser.evaluate("window.acqLod.requests") == 0
        coarse = _drawn(browser.screenshot())

        _open(browser, server.url)
        overview = browser.evaluate("window.acqLod.requests")
        _look_at_the_start(browser)
        stats = browser.evaluate(
            "({...window.acqLod, loaded: window.acqLod.loaded, look: undefined})"
        )
        fine = _drawn(browser.screenshot())
        # the point-size slider sets the chunks' size with the subset's
        browser.evaluate(
            "(() => { const s = document.getElementById('point-size'); s.value = 5;"
            " s.dispatchEvent(new Event('input')); })()"
        )
        sizes = browser.evaluate("window.acqLod.pointSizes")
        # the layer's box hides its chunks with its subset
        browser.evaluate("document.querySelector('#layers input').click()")
        hidden = _drawn(browser.screenshot())
        assert browser.errors == [], browser.console
        loaded = [int(key.split("/")[1]) for key in stats["loaded"]]
        sent = sum(len(server.chunk(0, c)) for c in loaded)
    assert overview == 0, "the whole street framed: no chunk is large enough on the screen"
    assert 0 in loaded, stats
    assert all(chunks[c]["min"][0] < 60 for c in loaded), f"a far chunk loaded: {loaded}"
    assert stats["chunks"] == len(loaded) and stats["failed"] == 0
    assert stats["points"] == 10_000 + 20_000 * len(loaded)
    assert stats["requests"] == len(loaded) and stats["bytes"] == sent
    assert fine > 1.5 * coarse, (coarse, fine)
    assert sizes == [5] * len(loaded)
    assert hidden == 0


def test_over_the_budget_the_chunk_out_of_view_is_dropped(browser: Browser, tmp_path: Path) -> None:
    path = _drive(tmp_path / "drive.laz", n=100_000)
    with ViewServer([path], max_points=5_000, run_points=10_000) as server:
        _open(browser, server.url + "?budget=15000")  # the subset and one chunk
        _look_at_the_start(browser)
        first = browser.evaluate("window.acqLod.loaded")
        _look_at_the_start(browser, x=195)  # the other end
        then = browser.evaluate("window.acqLod.loaded")
        points, requests = browser.evaluate("[window.acqLod.points, window.acqLod.requests]")
        assert browser.errors == [], browser.console
    assert (first, then) == (["0/0"], ["0/9"])
    assert (points, requests) == (15_000, 2)


def test_a_copc_cloud_loads_the_octree_nodes_of_the_end_in_view(
    browser: Browser, tmp_path: Path
) -> None:
    path = _drive(tmp_path / "drive.copc.laz", n=200_000)
    with ViewServer([path], max_points=10_000) as server:
        # room for the subset, the root (50,000) and two of eight ~19,000-point nodes
        _open(browser, server.url + "?budget=100000")
        overview = browser.evaluate("window.acqLod.loaded")
        _look_at_the_start(browser)
        loaded = [
            server.chunks[0][int(k.split("/")[1])] for k in browser.evaluate("window.acqLod.loaded")
        ]
        assert browser.errors == [], browser.console
    # the whole street in view: the root and the two nodes largest on the screen, which
    # the view onto the start leaves for two of its own
    assert len(overview) == 3 and "0/0" in overview
    assert [c.level for c in loaded].count(0) == 1 and len(loaded) == 3, loaded
    # level 1 halves the 200 m street: none of the far half's nodes
    assert all(c.lo[0] < 99 for c in loaded), f"a node of the far half: {loaded}"


def test_a_chunk_that_cannot_be_read_is_said_on_the_page(browser: Browser, tmp_path: Path) -> None:
    path = _drive(tmp_path / "drive.las", n=40_000)
    with ViewServer([path], max_points=2000, run_points=4000) as server:
        _open(browser, server.url)  # the whole street: no chunk loaded
        path.write_bytes(path.read_bytes()[:-36_000])  # 1,000 points (36 bytes each) gone
        _look_at_the_start(browser, x=195)
        failed, shown = browser.evaluate(
            "[window.acqLod.failed, document.getElementById('message').textContent]"
        )
    assert failed >= 1 and re.fullmatch(
        r"drive\.las: its finer points /data/0/chunk/[89]\.bin could not be loaded \(HTTP 500\)",
        shown,
    ), (failed, shown)
    assert browser.evaluate("window.acqError ?? null") is None  # the page goes on


def test_a_budget_that_is_no_number_is_named(browser: Browser, tmp_path: Path) -> None:
    path = _drive(tmp_path / "drive.laz", n=2000)
    with ViewServer([path], max_points=1000) as server:
        browser.open(server.url + "?budget=lots")
        error = browser.wait_for("window.acqError", timeout_s=60)
    assert error == "the page's URL: budget=lots is not a whole number of points"
