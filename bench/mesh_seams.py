"""The seams between views of `acq mesh --texture`, before and after they are levelled
(:mod:`acq.mesh.seams`): at each end of every edge joining two facets of two views, the
largest over the channels of the difference between the two views' colours there
(:func:`acq.mesh.seams.seam_colours`, levels), in each tile's atlas as sampled and as
levelled; and the CPU seconds the levelling took on the writer threads.

The drive is meshed as `acq mesh LOG --calib CALIB -o OUT.glb --texture` does it
(:func:`acq.mesh.drive.prepare_mesh`), observing (not replacing) the levelling. One JSON
line: ``ends`` (seam edge ends), ``levelled`` (the share of them within
:data:`acq.mesh.seams.MAX_STEP`), ``before`` and ``after`` (``mean``, ``p95``) over
those and over ``all`` of them, ``level_cpu_s`` (thread CPU), ``tiles``, ``seconds``.

Run as a script: ``python bench/mesh_seams.py LOG --calib CALIB [--work DIR]``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from acq.camera import calibfile
from acq.mesh import seams
from acq.mesh.drive import prepare_mesh
from acq.mesh.texture import Atlas


def _steps(atlas: Atlas, faces: np.ndarray, view_cam: np.ndarray, view_frame: np.ndarray,
           texels: int) -> np.ndarray:  # fmt: skip
    """(2E,) levels: each seam edge end's largest difference over the channels."""
    _, _, _, fa, fb = seams.seam_colours(atlas, faces, view_cam, view_frame, texels)
    return np.abs(fa - fb).max(axis=-1).reshape(-1)


def _figures(d: np.ndarray) -> dict[str, float]:
    if not d.size:
        return {"mean": 0.0, "p95": 0.0}
    return {"mean": round(float(d.mean()), 2), "p95": round(float(np.percentile(d, 95)), 2)}


def measure(logs: list[str], calib: str, out: Path) -> dict[str, Any]:
    before: list[np.ndarray] = []
    after: list[np.ndarray] = []
    cpu: list[float] = []
    level = seams.level_seams

    def observed(atlas: Atlas, faces: np.ndarray, vc: np.ndarray, vf: np.ndarray,
                 texels: int) -> int:  # fmt: skip
        before.append(_steps(atlas, faces, vc, vf, texels))
        t0 = time.thread_time()
        n = level(atlas, faces, vc, vf, texels)
        cpu.append(time.thread_time() - t0)
        after.append(_steps(atlas, faces, vc, vf, texels))
        return n

    t0 = time.perf_counter()
    seams.level_seams = observed  # type: ignore[assignment]
    try:
        paths = [Path(p) for p in logs]
        mj = prepare_mesh(paths, calibfile.load(Path(calib)), out, texels=8)
        mj.run()
    finally:
        seams.level_seams = level  # type: ignore[assignment]
    b = np.concatenate(before) if before else np.zeros(0)
    a = np.concatenate(after) if after else np.zeros(0)
    near = b <= seams.MAX_STEP
    return {
        "ends": int(b.size),
        "levelled": round(float(near.mean()), 4) if b.size else 0.0,
        "before": {"levelled": _figures(b[near]), "all": _figures(b)},
        "after": {"levelled": _figures(a[near]), "all": _figures(a)},
        "level_cpu_s": round(sum(cpu), 3),
        "tiles": len(cpu),
        "seconds": round(time.perf_counter() - t0, 1),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("logs", nargs="+", help="MCAP files or a folder")
    ap.add_argument("--calib", required=True)
    ap.add_argument("--work", type=Path, default=None, help="where the mesh goes (a temporary)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = a.work or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        print(json.dumps(measure(a.logs, a.calib, work / "t.glb")))


if __name__ == "__main__":
    main()
