"""bench/mesh_simplify.py on the short simulated drive in tiles: the facets of both meshes
counted and every vertex's distance to the simplified tile measured."""

from __future__ import annotations

from pathlib import Path

from tests.bench_scripts import load
from tests.mesh.test_mesh_cli import Drive, _ply

bench = load("mesh_simplify")


def test_each_tile_is_measured_against_its_simplified_self(
    short_drive: Drive, tmp_path: Path
) -> None:
    truth, calib = short_drive
    logs = [str(p) for p in truth.files]
    # in one file: the figures of the mesh the short drive gives
    row = bench.measure(logs, str(calib), 0.02, tmp_path)
    full, simple = _ply(tmp_path / "full.ply"), _ply(tmp_path / "simple.ply")
    assert row["facets"] == [full[2].shape[0], simple[2].shape[0]]
    assert row["vertices"] == full[0].shape[0] and 0 < row["kept"] < 0.9
    d = row["distance_m"]
    assert 0 <= d["p50"] <= d["p99"] <= d["max"] <= 0.03
    assert [t["file"] for t in row["tiles"]] == ["simple.ply"]
