"""`acq view FILE`'s first frame in headless Chromium: one JSON line per run.

For each FILE (default: a 10 M-point LAZ as `acq colorize` writes it, every attribute,
random colours along a 1 km street, written to a temporary folder), ``acq view FILE`` is
started and the page opened in headless Chromium (tests/browser.py, 1200 x 700, WebGL in
SwiftShader) as soon as the URL is printed. Reported: ``url_s`` (the command's start to
its URL), ``first_frame_s`` (to the page's first frame drawn: ``window.acqReady``),
``sent_mb`` (the page's, its libraries' and the layers' bytes received before it, by
Resource Timing), ``points_mb`` (of which the clouds' points), then ``intensity_s`` (from
choosing the colour mode "intensity" to its frame drawn: the attributes fetched,
``attributes_mb`` of them, and the points recoloured; ``intensity_again_s``, chosen again
after RGB: the recolouring alone) and ``server_peak_rss_mb``.
Run as a script: ``python bench/view_first_frame.py [FILE...] [--runs 3] [--mbit 50]``
(``--mbit``: the page's link throttled to that many megabits a second, Chromium's network
emulation, as a vehicle PC's Wi-Fi); skipped (a line saying so) without Chromium.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from tests.browser import CHROMIUM, Browser

READY = "window.acqReady === true || window.acqError !== undefined"
RECEIVED = (
    "performance.getEntriesByType('navigation').concat(performance.getEntriesByType('resource'))"
    ".filter((e) => e.name.includes(%r)).reduce((s, e) => s + e.encodedBodySize, 0)"
)

# a colour mode chosen as the user does; the seconds to its frame once the page has drawn it
CHOOSE = (
    "(() => { const c = document.getElementById('colour-mode'); window.benchChosen ="
    " performance.now(); c.value = %r; c.dispatchEvent(new Event('change')); })()"
)
DRAWN = "window.acqColourMode === %r && (performance.now() - window.benchChosen) / 1000"


def colour_mode_s(browser: Browser, mode: str) -> float:
    """The seconds from choosing the colour mode ``mode`` to its frame drawn."""
    browser.evaluate(CHOOSE % mode)
    return float(browser.wait_for(DRAWN % mode, timeout_s=300, interval_s=0.01))


def big_laz(path: Path, n: int = 10_000_000, part: int = 1_000_000) -> Path:
    """``n`` points as `acq colorize` writes them (LasStream: every attribute) along 1 km."""
    from acq.cloud.las import LasStream

    rng = np.random.default_rng(0)
    out = LasStream(path, crs="EPSG:25831", cameras=["left", "right"])
    for k in range(0, n, part):
        x = np.arange(k, k + part) / n * 1000.0
        xyz = np.stack([x, rng.uniform(-8, 8, part), rng.uniform(0, 10, part)], axis=1)
        xyz += np.array([431_000.0, 4_582_000.0, 12.0])  # a projected CRS's coordinates
        out.write(
            xyz, rng.integers(0, 256, (part, 3), dtype=np.uint8),
            1.764e9 + x / 10, rng.uniform(0, 4000, part).astype(np.float32),
            (np.arange(k, k + part) // 1000).astype(np.int32), rng.uniform(size=part) < 0.9,
            rng.integers(0, 2, part).astype(np.uint8), np.arange(k, k + part, dtype=np.int32),
        )  # fmt: skip
    out.close()
    return path


def first_frame(browser: Browser, path: Path) -> dict[str, object]:
    start = time.monotonic()
    acq = Path(sys.executable).parent / "acq"
    proc = subprocess.Popen([str(acq), "view", str(path)], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        url_s = time.monotonic() - start
        browser.open(line.split(" at ")[1].split()[0])
        browser.wait_for(READY, timeout_s=300, interval_s=0.01)
        frame_s = time.monotonic() - start
        error = browser.evaluate("window.acqError ?? null")
        sent_mb = round(browser.evaluate(RECEIVED % "/") / 1e6, 1)
        points_mb = round(browser.evaluate(RECEIVED % "/data/") / 1e6, 1)
        intensity_s = colour_mode_s(browser, "intensity")
        colour_mode_s(browser, "rgb")
        again_s = colour_mode_s(browser, "intensity")
        status = Path(f"/proc/{proc.pid}/status").read_text()
        rss_mb = int(status.split("VmHWM:")[1].split()[0]) / 1024
        return {
            "file": path.name, "mb": round(path.stat().st_size / 1e6, 1),
            "url_s": round(url_s, 2), "first_frame_s": round(frame_s, 2),
            "sent_mb": sent_mb, "points_mb": points_mb,
            "intensity_s": round(intensity_s, 2), "intensity_again_s": round(again_s, 2),
            "attributes_mb": round(browser.evaluate(RECEIVED % "attributes.bin") / 1e6, 1),
            "server_peak_rss_mb": round(rss_mb), "error": error,
        }  # fmt: skip
    finally:
        proc.terminate()
        proc.wait()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="*", type=Path)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--mbit", type=float, default=None, help="throttle the page's link")
    args = parser.parse_args()
    if not CHROMIUM.exists():
        print(json.dumps({"skipped": f"no Chromium at {CHROMIUM}"}))
        return
    with tempfile.TemporaryDirectory() as tmp, Browser(1200, 700) as browser:
        if args.mbit is not None:
            browser.throttle(args.mbit)
        for path in args.files or [big_laz(Path(tmp) / "big.laz")]:
            for _ in range(args.runs):
                print(json.dumps({"mbit": args.mbit} | first_frame(browser, path)), flush=True)


if __name__ == "__main__":
    main()
