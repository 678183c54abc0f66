"""`acq view` on a 10 M-point LAZ street in headless Chromium (tests/browser.py): the first
frame, then finer points as the view closes in (acq.view.lod, page/lod.js).

Data: a LAZ of ``--points`` (10,000,000) along a 500 m street (x 0-500 m in time order;
facades 8 m either side, 10 m high, two fifths of the points each; the road between),
random colours, in a projected CRS's coordinates, written once into ``--work``. Each run
starts `acq view` as a user does (a new process), opens the page in one Chromium (800 x
600) and gives one JSON line: ``first_frame_s`` (from the start of `acq view` to the
page's first frame), ``bytes_before`` (what the page received before it: the page,
three.js and the subset, without the chunks' index or chunks), then, the view set 10 m
from one facade (``facade``) and then along the street from its middle (``along``): the
chunks and points loaded, the requests, the bytes fetched and ``settle_s``, from the
view's move to the frame drawn once no chunk is left to load.

Run as a script: ``python bench/view_lod.py [--points N] [--runs R] [--work DIR]``.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from tests.browser import Browser

READY = "window.acqReady === true || window.acqError !== undefined"
SETTLED = "window.acqLod !== undefined && window.acqLod.idle && window.acqLod.updates > {n}"
FRAME = "new Promise((r) => requestAnimationFrame(() => requestAnimationFrame(() => r(1))))"
BYTES = """performance.getEntriesByType('navigation')
  .concat(performance.getEntriesByType('resource'))
  .filter((e) => !e.name.includes('/lod.json') && !e.name.includes('/chunk/'))
  .reduce((sum, e) => sum + e.transferSize, 0)"""
EAST, NORTH = 431_000.0, 4_582_000.0  # the street's origin (m, a projected CRS)


def street(path: Path, n: int) -> Path:
    """The LAZ street of ``n`` points (module docstring), written unless it exists."""
    import laspy

    if path.exists():
        return path
    rng = np.random.default_rng(7)
    x = np.sort(rng.uniform(0, 500, n))
    kind = rng.integers(0, 5, n)  # 0-1 the left facade, 2-3 the right, 4 the road
    facade = np.where(kind < 2, 8.0, -8.0) + rng.normal(0, 0.05, n)
    y = np.where(kind == 4, rng.uniform(-8, 8, n), facade)
    z = np.where(kind == 4, rng.normal(0, 0.02, n), rng.uniform(0, 10, n))
    header = laspy.LasHeader(point_format=7, version="1.4")
    header.scales, header.offsets = np.array([0.001] * 3), np.array([EAST, NORTH, 0.0])
    las = laspy.LasData(header)
    las.x, las.y, las.z = EAST + x, NORTH + y, z
    las.red, las.green, las.blue = (rng.integers(0, 65536, n, dtype=np.uint16) for _ in "rgb")
    las.write(path)
    return path


def view(
    browser: Browser, position: tuple[float, ...], target: tuple[float, ...]
) -> dict[str, Any]:
    """The figures of the level of detail once the view, set to ``position`` looking at
    ``target`` (m, the file's frame), has loaded all it wants and drawn it."""
    n = browser.evaluate("window.acqLod.updates")
    start = time.monotonic()
    browser.evaluate(f"window.acqLod.look({list(position)}, {list(target)})")
    browser.wait_for(SETTLED.format(n=n), timeout_s=300)
    browser.evaluate(FRAME)
    settle = time.monotonic() - start
    stats = browser.evaluate("({...window.acqLod, loaded: window.acqLod.loaded})")
    keys = ("chunks", "points", "requests", "bytes", "failed", "loaded")
    return {k: stats[k] for k in keys} | {"settle_s": round(settle, 2)}


def run(browser: Browser, path: Path) -> dict[str, Any]:
    acq = Path(sys.executable).parent / "acq"
    start = time.monotonic()
    process = subprocess.Popen([acq, "view", path], stdout=subprocess.PIPE, text=True)
    try:
        assert process.stdout is not None
        found = re.search(r"http://\S+/", process.stdout.readline())
        if found is None:
            raise RuntimeError("acq view printed no URL")
        browser.open(found.group(0))
        browser.wait_for(READY, timeout_s=300)
        first_frame = time.monotonic() - start
        error = browser.evaluate("window.acqError ?? null")
        if error is not None:
            raise RuntimeError(error)
        before = browser.evaluate(BYTES)
        browser.wait_for(SETTLED.format(n=0), timeout_s=60)
        facade = view(browser, (EAST + 250, NORTH - 2, 5), (EAST + 250, NORTH + 8, 5))
        along = view(browser, (EAST + 100, NORTH, 2), (EAST + 200, NORTH, 2))
    finally:
        process.terminate()
        process.wait(10)
    return {
        "first_frame_s": round(first_frame, 2), "bytes_before": before,
        "facade": facade, "along": along,
    }  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--points", type=int, default=10_000_000)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--work", type=Path, default=Path("/tmp/acq-bench-view-lod"))
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    path = street(args.work / f"street-{args.points}.laz", args.points)
    with Browser() as browser:
        for _ in range(args.runs):
            print(json.dumps(run(browser, path)), flush=True)


if __name__ == "__main__":
    main()
