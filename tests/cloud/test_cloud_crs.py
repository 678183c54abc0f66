"""`acq colorize --crs`: a CRS only where it is true (a georeferenced trajectory in it)."""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest

from acq.camera import calibfile
from acq.cli import main as acq_main
from acq.cloud.job import check_crs
from acq.errors import InputValueError
from acq.geometry.geodesy import WorldFrame
from acq.log.vehicle_log import read_vehicle
from acq.motion import Trajectory
from acq.sim.drive_log import DEFAULT_ORIGIN, write_drive_log


def _utm(lat: float, lon: float) -> str:
    """The WGS-84 UTM zone's EPSG code at (lat, lon) °."""
    zone = int((lon + 180) // 6) + 1
    return f"EPSG:{(32600 if lat >= 0 else 32700) + zone}"


def _colorize(log_dir: Path, calib: object, out: Path, *argv: str) -> int:
    cal = log_dir / "calib.yaml"
    calibfile.save(calib, cal)  # type: ignore[arg-type]
    files = sorted(map(str, log_dir.glob("*.mcap")))
    return acq_main(
        ["colorize", *files, "--calib", str(cal), "-o", str(out), "--no-preview", *argv]
    )


@pytest.mark.parametrize("odometry_hz", [50.0, 0.0], ids=["with CAN", "GNSS alone"])
def test_gnss_fixes_put_the_cloud_in_the_crs(tmp_path: Path, odometry_hz: float) -> None:
    truth = write_drive_log(tmp_path, 1.0, gnss_hz=10.0, odometry_hz=odometry_hz)
    crs = _utm(DEFAULT_ORIGIN[0], DEFAULT_ORIGIN[1])
    out = tmp_path / "c.laz"
    assert _colorize(tmp_path, truth.calibration, out, "--crs", crs) == 0
    las = laspy.read(out)
    assert las.header.parse_crs().equals(pyproj.CRS.from_user_input(crs))
    # the vehicle starts at the street's origin: the cloud lies around its projection
    x0, y0 = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(
        DEFAULT_ORIGIN[1], DEFAULT_ORIGIN[0]
    )
    centre = np.array([np.median(las.x), np.median(las.y)])
    assert np.linalg.norm(centre - [x0, y0]) < 50, (centre, (x0, y0))
    # and where the ENU cloud of the same fixes says, to a centimetre or so
    enu = tmp_path / "enu.las"
    assert _colorize(tmp_path, truth.calibration, enu) == 0
    local = laspy.read(enu)
    fixes = read_vehicle(list(truth.files)).fixes  # the ENU plane is at the first fix
    first = (fixes.lat[0], fixes.lon[0], fixes.alt[0])
    geo = WorldFrame("enu", first).to_geodetic(np.stack([local.x, local.y, local.z], axis=1))
    x, y = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(geo[1], geo[0])
    d = np.hypot(np.asarray(las.x) - x, np.asarray(las.y) - y)
    assert np.median(d) < 0.02, np.percentile(d, [50, 99])


def test_a_dead_reckoned_cloud_is_refused_a_crs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    truth = write_drive_log(tmp_path, 0.5)
    out = tmp_path / "c.las"
    assert _colorize(tmp_path, truth.calibration, out, "--crs", "EPSG:25831") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert "CAN odometry" in err and "dead reckoning" in err and "GNSS fixes" in err, err
    assert not out.exists()


@pytest.mark.parametrize(
    ("argv", "expect"),
    [
        (["--crs", "EPSG:25831", "--frame", "laser"], "laser frame"),
        (["--crs", "EPSG:4326"], "not a projected CRS"),
    ],
)
def test_a_crs_that_cannot_be_true_is_refused_before_any_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], expect: str
) -> None:
    # neither the log nor the calibration exists: refused before they are read
    base = ["colorize", str(tmp_path / "none.mcap"), "--calib", str(tmp_path / "none.yaml")]
    assert acq_main([*base, "-o", str(tmp_path / "c.las"), *argv]) == 2
    err = capsys.readouterr().err
    assert expect in err and err.count("\n") == 1, err


def _traj(frame: str, origin: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Trajectory:
    t = np.array([0, 10**9])
    return Trajectory(t, np.stack([np.eye(3)] * 2), np.zeros((2, 3)), frame, origin)


def test_only_a_trajectory_in_the_crs_itself_gives_it() -> None:
    check_crs("EPSG:25831", _traj("EPSG:25831"), True, "given")
    with pytest.raises(InputValueError, match="in enu, not reprojected"):
        check_crs("EPSG:25831", _traj("enu", (41.4, 2.1, 50.0)), True, "given")
    with pytest.raises(InputValueError, match="in EPSG:25830, not reprojected"):
        check_crs("EPSG:25831", _traj("EPSG:25830"), True, "given")
    with pytest.raises(InputValueError, match="origin offset"):
        check_crs("EPSG:25831", _traj("EPSG:25831", (400_000.0, 4_500_000.0, 0.0)), True, "x")
    with pytest.raises(InputValueError, match="no tie to the Earth"):
        check_crs("EPSG:25831", _traj("odometry"), True, "CAN odometry")
    with pytest.raises(InputValueError, match="laser frame"):
        check_crs("EPSG:25831", _traj("EPSG:25831"), False, "given")
