"""bench/mesh_seams.py on the short simulated drive: the seams of each tile measured as
sampled and as levelled, through acq mesh --texture's own run (a real MCAP log)."""

from __future__ import annotations

from pathlib import Path

from acq.mesh import seams
from tests.bench_scripts import load
from tests.mesh.test_mesh_cli import Drive

bench = load("mesh_seams")


def test_seams_are_measured_before_and_after_levelling(short_drive: Drive, tmp_path: Path) -> None:
    truth, calib = short_drive
    row = bench.measure([str(p) for p in truth.files], str(calib), tmp_path / "t.glb")
    assert (tmp_path / "t.glb").is_file()
    assert row["tiles"] >= 1 and row["ends"] > 0 and row["ends"] % 2 == 0
    assert 0.5 < row["levelled"] <= 1
    before, after = row["before"]["levelled"], row["after"]["levelled"]
    assert after["mean"] < before["mean"] / 2 and after["p95"] < before["p95"]
    assert before["p95"] <= seams.MAX_STEP
    assert row["after"]["all"]["mean"] < row["before"]["all"]["mean"]
    assert row["level_cpu_s"] > 0
    # the levelling put back as it was
    assert seams.level_seams.__name__ == "level_seams"
