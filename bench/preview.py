"""Speed of `acq colorize`'s preview image on a whole drive's cloud.

Data: a drive log (``LOG``: its folder, with ``calib.yaml`` beside the files, as
``python -m acq.sim.drive_log DIR 60`` writes; default: a new 60 s simulated drive),
coloured once with `acq colorize`'s defaults but no preview (the chunks' results kept in
memory, every scan: what the preview gets from a log of up to 4 M points); then the
preview drawn ``--runs`` times (the first run discarded: numba's compiled kernels are
loaded from its cache then).

One JSON line: the cloud's points, the image's size, the median and best wall seconds
and the median CPU seconds of :func:`acq.cloud.preview.preview_image` (drawing) and of
:func:`preview_png` (drawing, encoding and writing); target: ``preview_png`` at most
0.5 s for a 60 s drive.

Run as a script: ``python bench/preview.py [LOG] [--runs N]``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any, cast

import numpy as np

from acq.camera import calibfile
from acq.cloud.chunks import ChunkResult, cloud_of
from acq.cloud.colorize import run
from acq.cloud.points import Cloud
from acq.cloud.preview import preview_image, preview_png
from acq.log.drive_log import DriveLog


def _cloud(log: Path, work: Path) -> Cloud:
    """The cloud of ``log`` as `acq colorize` would hand it to the preview."""
    calib = calibfile.load(log / "calib.yaml")
    results: list[ChunkResult] = []
    report = run([log], calib, work / "c.ply", preview=None, results=results)
    # the chunks' results and the log's camera names are what the preview needs
    index = cast(
        DriveLog, SimpleNamespace(clock=np.zeros((0, 2), np.int64), n_frames=report.frames)
    )
    return cloud_of(results, index, list(calib.cameras))


def _times(fn: Any, runs: int) -> dict[str, float]:
    """Median and best wall seconds of ``fn`` over ``runs`` runs after a first, and the
    median CPU seconds (this process: the drawing is one thread; on a busy machine the
    wall time is not the work)."""
    wall, cpu = [], []
    for _ in range(runs + 1):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return {
        "median": round(statistics.median(wall[1:]), 3),
        "best": round(min(wall[1:]), 3),
        "cpu_median": round(statistics.median(cpu[1:]), 3),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", nargs="?", type=Path, help="a drive log's folder with calib.yaml")
    ap.add_argument("--runs", type=int, default=5)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        log = args.log
        if log is None:
            from acq.sim.drive_log import write_drive_log

            log = work / "drive"
            truth = write_drive_log(log, 60.0)
            calibfile.save(truth.calibration, log / "calib.yaml")
        cloud = _cloud(log, work)
        img = preview_image(cloud)
        draw = _times(lambda: preview_image(cloud), args.runs)
        png = _times(lambda: preview_png(work / "p.png", cloud), args.runs)
        line = {
            "result": "preview",
            "points": cloud.size,
            "cameras": list(cloud.camera_names),
            "image_wh": [int(img.shape[1]), int(img.shape[0])],
            "preview_image_s": draw,
            "preview_png_s": png,
            "target_s": 0.5,
        }
        print(json.dumps(line))


if __name__ == "__main__":
    main()
