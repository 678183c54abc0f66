"""The URL before the decoding: acq view serves at once and packs its clouds on a thread;
a cloud's URL answers 202 (Accepted, Retry-After: a browser logs a 503 as a console
error) until its points are ready and the page says
"decoding NAME…" meanwhile, then draws it; points found bad while decoding are said on the
page and once to the server's caller, never a page left waiting."""

from __future__ import annotations

import threading
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest

from acq.view import points_payload
from acq.view.server import ViewServer
from tests.browser import Browser
from tests.view.layer_files import las_cloud, unpack
from tests.view.test_page import READY, WALL, _share

FAR = (431_000.0, 4_582_000.0, 12.0)


@pytest.fixture
def held(monkeypatch: pytest.MonkeyPatch) -> Iterator[threading.Event]:
    """The server's decoding held back until the event is set, as a large file's takes
    seconds (the real payload then, of the real file); requests wait 0.2 s, not 2, before
    their 202."""
    gate = threading.Event()

    def slow(path: Path, max_points: int) -> points_payload.Split:
        gate.wait(60)
        return points_payload.split_payload(path, max_points)

    monkeypatch.setattr("acq.view.server.split_payload", slow)
    monkeypatch.setattr("acq.view.server._POLL_S", 0.2)
    yield gate
    gate.set()


def test_a_cloud_decoding_answers_202_then_its_points(
    tmp_path: Path, held: threading.Event
) -> None:
    path, _, _ = las_cloud(tmp_path / "c.laz", n=2000, at=FAR)
    with ViewServer([path]) as server:
        (layer,) = server.listing()  # listed before its points are decoded
        assert (layer["count"], layer["shown"]) == (2000, 2000)
        url = server.url.rstrip("/") + layer["url"]
        with urllib.request.urlopen(url, timeout=10) as r:
            assert r.status == 202 and r.headers["Retry-After"] == "0"
            assert r.read() == b"decoding c.laz"
        with urllib.request.urlopen(url.replace("points.bin", "attributes.bin"), timeout=10) as r:
            assert r.status == 202 and r.read() == b"decoding c.laz"  # its attributes alike
        assert not server.wait(0)
        held.set()
        assert server.wait(30)
        with urllib.request.urlopen(url, timeout=10) as r:
            points = r.read()
        with urllib.request.urlopen(url.replace("points.bin", "attributes.bin"), timeout=10) as r:
            assert unpack(points, r.read())["shown"] == 2000


def test_the_page_says_decoding_then_draws_the_cloud(
    browser: Browser, tmp_path: Path, held: threading.Event
) -> None:
    path, _, _ = las_cloud(tmp_path / "wall.laz", n=30_000, at=FAR, rgb=WALL)
    with ViewServer([path]) as server:
        browser.open(server.url)
        browser.wait_for("document.getElementById('message').textContent === 'decoding wall.laz…'")
        assert browser.evaluate("window.acqReady") is False
        held.set()
        browser.wait_for(READY, timeout_s=60)
        assert browser.evaluate("window.acqError ?? null") is None
        assert browser.errors == [], browser.console
        assert _share(browser.screenshot(), WALL, 4) > 0.01


def test_points_found_bad_while_decoding_are_said_on_the_page(
    browser: Browser, tmp_path: Path
) -> None:
    laz, _, _ = las_cloud(tmp_path / "good.laz", n=20_000)
    cut = tmp_path / "cut.laz"  # its header whole, its points cut: found bad only decoding
    cut.write_bytes(laz.read_bytes()[: laz.stat().st_size // 2])
    said: list[str] = []
    with ViewServer([laz, cut], on_error=said.append) as server:
        browser.open(server.url)
        browser.wait_for(READY, timeout_s=60)
        error = browser.evaluate("window.acqError ?? null")
        shown = browser.evaluate("document.getElementById('message').textContent")
    assert said == [error] == [shown], (said, error, shown)
    assert error.startswith(f"{cut}: its points cannot be read (") and "\n" not in error
