"""How far `acq mesh --simplify M` moves the surface: the distance of every vertex of the
mesh meshed without it to the simplified mesh, tile by tile (the same tiles: the same
track), and how many facets are left.

Both meshes are written as PLY (x y z double) into ``--work`` by `acq mesh LOG --calib
CALIB -o full.ply` and `... -o simple.ply --simplify M`; each distance is
:func:`acq.mesh.simplify.surface_distance`, exact above M/4 (so the largest and the
99th percentile are exact whenever they pass M/4; below it, an upper bound).

One JSON line: ``facets`` (full, simplified), ``kept`` (their ratio), ``distance_m``
(``max``, ``p99``, ``p50`` over all vertices) and per tile, ``seconds`` of each run.

Run as a script: ``python bench/mesh_simplify.py LOG --calib CALIB [--simplify M]
[--work DIR]``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from plyfile import PlyData

from acq.cli import main as acq_main
from acq.mesh.simplify import surface_distance


def read_ply(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(xyz (V,3) m, faces (F,3)) of one of acq mesh's PLY files."""
    data = PlyData.read(str(path))
    v = data["vertex"].data
    faces = np.stack(data["face"].data["vertex_indices"]).astype(np.int64)
    return np.stack([v["x"], v["y"], v["z"]], axis=1), faces


def tiles(out: Path) -> list[Path]:
    """The files acq mesh wrote for ``out``: itself, or its tiles in order."""
    return [out] if out.exists() else sorted(out.parent.glob(f"{out.stem}_*{out.suffix}"))


def mesh(logs: list[str], calib: str, out: Path, *argv: str) -> float:
    """Run acq mesh to ``out``; its seconds."""
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        code = acq_main(["mesh", *logs, "--calib", calib, "-o", str(out), "--force", *argv])
    if code != 0:
        raise SystemExit(f"acq mesh -o {out} failed ({code})")
    return time.perf_counter() - t0


def measure(logs: list[str], calib: str, tolerance_m: float, work: Path) -> dict[str, Any]:
    full, simple = work / "full.ply", work / "simple.ply"
    seconds = [mesh(logs, calib, full), mesh(logs, calib, simple, "--simplify", f"{tolerance_m}")]
    pairs = list(zip(tiles(full), tiles(simple), strict=True))
    per_tile, all_d, facets = [], [], [0, 0]
    for a, b in pairs:
        xyz, faces = read_ply(a)
        s_xyz, s_faces = read_ply(b)
        d = surface_distance(xyz, s_xyz, s_faces, exact_over_m=tolerance_m / 4)
        all_d.append(d)
        facets[0] += faces.shape[0]
        facets[1] += s_faces.shape[0]
        per_tile.append({"file": b.name, "facets": [faces.shape[0], s_faces.shape[0]],
                         "max_m": round(float(d.max()), 4)})  # fmt: skip
    d = np.concatenate(all_d)
    return {
        "simplify_m": tolerance_m,
        "facets": facets,
        "kept": round(facets[1] / facets[0], 4),
        "distance_m": {
            "max": round(float(d.max()), 4),
            "p99": round(float(np.percentile(d, 99)), 4),
            "p50": round(float(np.percentile(d, 50)), 4),
        },
        "vertices": int(d.size),
        "tiles": per_tile,
        "seconds": [round(s, 1) for s in seconds],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("logs", nargs="+", help="MCAP files or a folder")
    ap.add_argument("--calib", required=True)
    ap.add_argument("--simplify", type=float, default=0.02, help="metres (default 0.02)")
    ap.add_argument("--work", type=Path, default=None, help="where the meshes go (a temporary)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = a.work or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        print(json.dumps(measure(a.logs, a.calib, a.simplify, work)))


if __name__ == "__main__":
    main()
