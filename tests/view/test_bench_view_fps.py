"""bench/view_fps.py once, briefly, in headless Chromium (tests/browser.py): a LAZ cloud it
writes, subsampled by the server, orbited by the page's hook; the frames counted are the
view's turns (the north arrow turned by as many steps). Not timed: the figures are the
bench's to report."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.bench_scripts import load
from tests.browser import Browser

bench = load("view_fps")


def test_the_bench_orbits_a_cloud_and_counts_its_frames(browser: Browser, tmp_path: Path) -> None:
    path = bench.write_laz(tmp_path / "c.laz", 30_000)
    row = bench.measure(browser, path, seconds=0.5, step_deg=2.0, max_points=10_000)
    assert json.loads(json.dumps(row)) == row  # one JSON line
    assert (row["file"], row["points"], row["drawn"]) == ("c.laz", 30_000, 10_000)
    assert row["frames"] > 0 and 0.5 <= row["orbit_s"] < 5
    assert row["fps"] == pytest.approx(row["frames"] / row["orbit_s"], rel=0.01)
    assert "SwiftShader" in row["renderer"] and "SwiftShader" in row["software"]
    assert row["antialias"] is False  # no multisampling on a software renderer
    # each frame counted turned the view by the step: the arrow (framed at 45 degrees) too
    north = browser.evaluate("window.acqOverlays.northDeg")
    assert (north - 45 - 2.0 * row["frames"] + 180) % 360 - 180 == pytest.approx(0, abs=0.01)
    assert browser.errors == [], browser.console
