"""bench/view_first_frame.py on small files: its LAZ as `acq colorize` writes it (every
attribute) and its figures of a real `acq view` run in headless Chromium."""

from __future__ import annotations

from pathlib import Path

from acq.view.points_payload import payload
from tests.bench_scripts import load
from tests.browser import Browser
from tests.view.layer_files import unpack


def test_the_bench_measures_a_real_first_frame(browser: Browser, tmp_path: Path) -> None:
    bench = load("view_first_frame")
    path = bench.big_laz(tmp_path / "small.laz", n=20_000, part=10_000)
    got = unpack(payload(path, 100_000))
    assert got["shown"] == 20_000 and got["flags"] == 63 and got["names"] == ["left", "right"]
    run = bench.first_frame(browser, path)
    assert run["error"] is None and run["file"] == "small.laz"
    assert 0 < run["url_s"] < run["first_frame_s"]
    # before the first frame: the header, the cameras' names (4-byte aligned), 15 bytes a
    # point (positions and sRGB); the other 14 bytes a point when "intensity" is chosen
    assert run["points_mb"] == round((80 + 12 + 15 * 20_000) / 1e6, 1)
    assert run["attributes_mb"] == round((80 + 12 + 14 * 20_000) / 1e6, 1)
    assert 0 < run["intensity_again_s"] and 0 < run["intensity_s"] < 30
    assert run["sent_mb"] > run["points_mb"] and run["server_peak_rss_mb"] > 0
