"""Frames per second of `acq view`'s page while the view orbits: one JSON line per cloud.

Clouds: the demo's (``cloud.ply`` of ``--demo DIR``; default: a new ``acq demo --seconds
10`` in a temporary folder, about 340,000 points) and LAZ clouds of ``--millions`` million
points (default 2 and 10) written here by acq's LasStream (random points in a 100 x 20 x
10 m street-sized box, random colours, EPSG:25831), each served by
:class:`acq.view.server.ViewServer` with the default ``--max-points`` (2 M: the 10 M cloud
is drawn as an evenly spread 2 M subset). Each is opened in headless Chromium
(tests/browser.py: WebGL in SwiftShader, a software renderer on the CPU; a GPU draws these
many times faster), 800 x 600 pixels, points 2 px; once the first frame is drawn, the page's
``window.acqOrbit`` (acq/view/page/orbit.js) turns the view by ``--step`` degrees about the
target at every animation frame for ``--seconds`` and counts the frames.

Reported: ``points`` in the file, ``drawn`` (points sent to the page), ``serve_s`` (the
server's start: checking and packing the file), ``first_frame_s`` (from opening the page
to its first frame drawn), ``frames``, ``orbit_s``, ``fps``, ``antialias`` (the page
multisamples on a GPU only) and ``renderer`` (WebGL's own
name for it, which says SwiftShader). Run as a script: ``python bench/view_fps.py [--demo
DIR] [--millions 2 10] [--seconds 10]``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/browser.py: the harness
from acq.view.server import DEFAULT_MAX_POINTS, ViewServer
from tests.browser import Browser

READY = "window.acqReady === true || window.acqError !== undefined"
RENDERER = """(() => {
  const gl = document.createElement('canvas').getContext('webgl2');
  const info = gl && gl.getExtension('WEBGL_debug_renderer_info');
  return info ? gl.getParameter(info.UNMASKED_RENDERER_WEBGL) : null;
})()"""
_PART = 1_000_000  # points written at a time
_CORNER = np.array([431_000.0, 4_582_000.0, 0.0])  # the box's, in EPSG:25831 (m)


def write_laz(path: Path, points: int, seed: int = 0) -> Path:
    """A LAZ cloud of ``points`` random points in a 100 x 20 x 10 m box in EPSG:25831,
    random colours, written by acq's LasStream as `acq colorize` writes one."""
    from acq.cloud.las import LasStream

    rng = np.random.default_rng(seed)
    out = LasStream(path, crs="EPSG:25831", cameras=["left"])
    try:
        for start in range(0, points, _PART):
            n = min(_PART, points - start)
            xyz = rng.uniform([0, 0, 0], [100, 20, 10], (n, 3)) + _CORNER
            out.write(
                xyz, rng.integers(0, 256, (n, 3), dtype=np.uint8),
                np.linspace(start, start + n, n) * 1e-5, np.ones(n, np.float32),
                np.full(n, start // 1081, np.int32), np.ones(n, bool), np.zeros(n, np.uint8),
                np.zeros(n, np.int32),
            )  # fmt: skip
    except BaseException:
        out.abort()
        raise
    out.close()
    return path


def demo_cloud(folder: Path, seconds: float = 10) -> Path:
    """The cloud of a new `acq demo --seconds SECONDS` in ``folder``."""
    acq = Path(sys.executable).with_name("acq")
    subprocess.run(
        [str(acq), "demo", "--out", str(folder), "--seconds", str(seconds)],
        check=True, stdout=subprocess.DEVNULL,
    )  # fmt: skip
    return folder / "cloud.ply"


def measure(
    browser: Browser, path: Path, seconds: float, step_deg: float,
    max_points: int = DEFAULT_MAX_POINTS,
) -> dict[str, Any]:  # fmt: skip
    """The figures of the module for the cloud ``path`` orbited ``seconds`` in ``browser``."""
    t0 = time.perf_counter()
    with ViewServer([path], max_points=max_points) as server:
        serve_s = time.perf_counter() - t0
        (layer,) = server.listing()
        t1 = time.perf_counter()
        browser.open(server.url, timeout_s=120)
        browser.wait_for(READY, timeout_s=300)
        first_frame_s = time.perf_counter() - t1
        error = browser.evaluate("window.acqError ?? null")
        if error is not None:
            raise RuntimeError(f"{path}: the page failed: {error}")
        orbit = browser.evaluate(f"window.acqOrbit({seconds}, {step_deg})")
        renderer = browser.evaluate(RENDERER)
        antialias = browser.evaluate("window.acqAntialias")
    return {
        "bench": "view_fps",
        "file": path.name,
        "points": layer["count"],
        "drawn": layer["shown"],
        "serve_s": round(serve_s, 2),
        "first_frame_s": round(first_frame_s, 2),
        "frames": orbit["frames"],
        "orbit_s": round(orbit["seconds"], 2),
        "fps": round(orbit["frames"] / orbit["seconds"], 2),
        "viewport": [browser.width, browser.height],
        "renderer": renderer,
        "antialias": antialias,  # the page turns multisampling off on a software renderer
        "software": "SwiftShader: WebGL on the CPU (headless Chromium); a GPU is far faster",
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--demo", type=Path, help="an acq demo's folder (default: a new one)")
    parser.add_argument("--millions", type=float, nargs="*", default=[2, 10])
    parser.add_argument("--seconds", type=float, default=10.0, help="orbiting time (s)")
    parser.add_argument("--step", type=float, default=1.0, help="degrees turned a frame")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="acq-view-fps-") as tmp:
        work = Path(tmp)
        clouds = [args.demo / "cloud.ply" if args.demo else demo_cloud(work / "demo")]
        clouds += [write_laz(work / f"{m:g}M.laz", round(m * 1e6)) for m in args.millions]
        with Browser() as browser:
            for path in clouds:
                print(json.dumps(measure(browser, path, args.seconds, args.step)), flush=True)


if __name__ == "__main__":
    main()
