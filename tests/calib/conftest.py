"""Fixtures shared by the calibration tests of this folder."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from tests.conftest import once_per_run

# drives from which neither the pose check nor the time offset can be had: the reason
# each command must give, and how the drive is written (sim/drive_log.py)
UNDECIDABLE = {
    "still": ("does not move", {"speed_kmh": 0.0}),
    "no_strengths": ("return strengths", {"intensities": False}),
    "no_odometry": ("motion", {"odometry_hz": 0.0}),
}


@pytest.fixture(scope="session")
def undecidable_drives(
    tmp_path_factory: pytest.TempPathFactory,
) -> dict[str, tuple[list[Path], Path, str]]:
    """1 s simulated drives, one per case of UNDECIDABLE, written once in a test run (the
    tests only read them): name -> (the log's files, its true calibration, the reason)."""

    def make(folder: Path) -> dict[str, Any]:
        from acq.camera import calibfile
        from acq.sim.drive_log import write_drive_log

        made = {}
        for name, (_, kwargs) in UNDECIDABLE.items():
            truth = write_drive_log(folder / name, 1.0, pattern_at=None, **kwargs)  # type: ignore[arg-type]
            calib = folder / name / "calib.yaml"
            calibfile.save(truth.calibration, calib)
            made[name] = {"files": [str(f) for f in truth.files], "calib": str(calib)}
        return made

    _, made = once_per_run(tmp_path_factory, "undecidable_drives", make)
    return {
        name: ([Path(f) for f in m["files"]], Path(m["calib"]), UNDECIDABLE[name][0])
        for name, m in made.items()
    }
