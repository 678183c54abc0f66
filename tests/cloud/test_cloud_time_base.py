"""A cloud says when its UTC cannot be trusted: ``acq colorize``'s report notes it, a
PLY's comments and a LAS file's VLR (acq, 2) say why; a log whose time base vouches for
its UTC gets neither."""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
from plyfile import PlyData

from acq.camera import calibfile
from acq.cloud.colorize import run
from acq.cloud.las import TIME_BASE_VLR
from acq.cloud.report import Report
from acq.cloud.writer import CloudWriter
from acq.sim.drive_log import write_drive_log
from acq.time.host_clock_summary import utc_doubt

DOUBT = "host clock unsynchronised in 3 of 3 readings: its UTC may be off"


def _time_base_vlr(path: Path) -> str | None:
    las = laspy.read(path)
    found = [v for v in las.header.vlrs if (v.user_id, v.record_id) == TIME_BASE_VLR[:2]]
    return found[0].record_data.decode() if found else None


def test_utc_doubt_reads_the_time_base_metadata() -> None:
    assert utc_doubt({"time_base": {"utc_trusted": "yes", "warnings": ""}}) is None
    assert utc_doubt({"time_base": {"utc_trusted": "no", "warnings": DOUBT}}) == DOUBT
    assert "no time base" in (utc_doubt({"clock": {}}) or "")


def test_the_writer_says_why_in_las_and_ply_and_nothing_when_trusted(tmp_path: Path) -> None:
    clock = np.array([[0, 1_700_000_000 * 10**9]], np.int64)
    for name, doubt in (("doubt.las", DOUBT), ("trusted.las", None), ("doubt.ply", DOUBT)):
        CloudWriter(tmp_path / name, None, clock, Report(name), utc_doubt=doubt).close()
    assert _time_base_vlr(tmp_path / "doubt.las") == DOUBT
    assert _time_base_vlr(tmp_path / "trusted.las") is None
    assert f"UTC not trusted: {DOUBT}" in PlyData.read(str(tmp_path / "doubt.ply")).comments


def test_colorize_of_a_log_without_a_time_base_notes_it(tmp_path: Path) -> None:
    truth = write_drive_log(tmp_path, 1.0, pattern_at=None)
    calib = tmp_path / "calib.yaml"
    calibfile.save(truth.calibration, calib)
    out = tmp_path / "c.las"
    report = run(list(truth.files), calibfile.load(calib), out, frame="laser")
    notes = [n for n in report.notes if n.startswith("UTC not trusted")]
    assert notes == [
        "UTC not trusted (the points' times): the log has no time base: whether the host "
        "clock was synchronised is unknown"
    ]
    assert "no time base" in (_time_base_vlr(out) or "")
