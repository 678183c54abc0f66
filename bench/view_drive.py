"""Times of `acq view` on a drive (a ``.mcap`` log), in headless Chromium (tests/browser.py).

Data: ``LOG`` (default: the demo's drive, made by ``acq demo --out`` in a temporary folder,
about 35 s), with ``calib.yaml`` beside it. Two cases, ``--runs`` times each: ``found``,
the log in its own folder (the cloud `acq colorize` wrote beside it is found), and
``coloured``, the log and calib.yaml alone in a scratch folder (the server colours the
cloud on a thread into an empty cache).

One JSON line per run: ``start_s`` (the server's construction and start: the log read,
re-timed and given its trajectory), ``drive_json_bytes``, ``first_frame_s`` (from the
start to the page's first frame drawn) and ``cloud_s`` (from the start to the drive's
cloud drawn in the page); Chromium draws WebGL in software (SwiftShader). Target: the
page's first frame within 2 s of the start on the demo's drive.

Run as a script: ``python bench/view_drive.py [LOG] [--runs N]``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the browser: a test helper

from acq.view.server import ViewServer
from tests.browser import Browser, chromium_or_skip

READY = "window.acqReady === true || window.acqError !== undefined"


def run_once(browser: Browser, log: Path, cache: Path) -> dict[str, Any]:
    """One start of the server on ``log`` and one load of the page (module docstring)."""
    t0 = time.perf_counter()
    with ViewServer([log], cache=cache) as server:
        t1 = time.perf_counter()
        with urllib.request.urlopen(f"{server.url}data/0/drive.json", timeout=60) as r:
            data = r.read()
        browser.open(server.url)
        browser.wait_for(READY, timeout_s=120)
        if browser.evaluate("window.acqError ?? null") is not None:
            raise RuntimeError(browser.evaluate("window.acqError"))
        t2 = time.perf_counter()
        browser.wait_for("window.acqDriveCloud?.[0]", timeout_s=600, interval_s=0.02)
        t3 = time.perf_counter()
    return {
        "start_s": round(t1 - t0, 3),
        "drive_json_bytes": len(data),
        "first_frame_s": round(t2 - t1, 3),
        "cloud_s": round(t3 - t1, 3),
        "cloud": json.loads(data)["cloud"]["status"],
    }


def demo_log(work: Path) -> Path:
    """The demo's drive, made by `acq demo` in ``work``/demo."""
    subprocess.run([sys.executable, "-m", "acq.cli", "demo", "--out", str(work / "demo")],
                   check=True, stdout=subprocess.DEVNULL)  # fmt: skip
    return work / "demo" / "demo.mcap"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("log", nargs="?", type=Path, help="a .mcap log, calib.yaml beside it")
    parser.add_argument("--runs", type=int, default=2)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        log = args.log or demo_log(work)
        bare = work / "bare"
        bare.mkdir()
        shutil.copy2(log, bare)
        shutil.copy2(log.parent / "calib.yaml", bare)
        with Browser(width=1200, height=800, binary=chromium_or_skip()) as browser:
            for case, path in (("found", log), ("coloured", bare / log.name)):
                for k in range(args.runs):
                    cache = work / f"cache-{case}-{k}"  # empty: the cloud coloured each time
                    line = {"case": case, "log": log.name} | run_once(browser, path, cache)
                    print(json.dumps(line), flush=True)


if __name__ == "__main__":
    main()
