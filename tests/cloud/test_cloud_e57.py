"""E57 written part by part (acq.cloud.e57.E57Stream), read back through libE57."""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pyproj

from acq.camera import calibfile
from acq.cli import main as acq_main
from acq.cloud.e57 import E57Stream
from acq.provenance import SOFTWARE
from acq.sim.drive_log import write_drive_log
from acq.time.gpstime import utc_to_gps
from tests.cloud.test_cloud_files import _points

_TYPES = {
    "cartesianX": "d", "cartesianY": "d", "cartesianZ": "d", "timeStamp": "d",
    "intensity": "f", "colorRed": "B", "colorGreen": "B", "colorBlue": "B",
    "isColorInvalid": "B", "rowIndex": "q",
}  # fmt: skip


def _read(path: Path) -> tuple[dict[str, np.ndarray], object, str]:
    """Every point field of the file's first scan, the scan node and the root's
    coordinateMetadata."""
    from pye57 import libe57

    imf = libe57.ImageFile(str(path), "r")
    scan = libe57.StructureNode(libe57.VectorNode(imf.root().get("data3D")).get(0))
    points = libe57.CompressedVectorNode(scan.get("points"))
    n = points.childCount()
    arrays = {k: np.zeros(n, dtype=t) for k, t in _TYPES.items()}
    buffers = libe57.VectorSourceDestBuffer()
    for k, a in arrays.items():
        buffers.append(libe57.SourceDestBuffer(imf, k, a, n, True, True))
    reader = points.reader(buffers)
    assert reader.read() == n
    reader.close()
    return arrays, (imf, scan), libe57.StringNode(imf.root().get("coordinateMetadata")).value()


def test_e57_in_parts_keeps_every_field(tmp_path: Path) -> None:
    parts = [_points(n, seed) for seed, n in enumerate((800, 0, 1700))]
    out = E57Stream(tmp_path / "c.e57", crs="EPSG:25831", comments=["frame world"])
    for p in parts:
        out.write(*p)
    size = out.close()
    assert size == (tmp_path / "c.e57").stat().st_size and not (tmp_path / "c.e57.tmp").exists()
    got, (imf, scan), wkt = _read(tmp_path / "c.e57")
    xyz, rgb, utc, intensity, scan_i, coloured = (
        np.concatenate(c) for c in zip(*parts, strict=True)
    )
    np.testing.assert_array_equal(np.stack([got[f"cartesian{a}"] for a in "XYZ"], axis=1), xyz)
    np.testing.assert_array_equal(
        np.stack([got[f"color{c}"] for c in ("Red", "Green", "Blue")], 1), rgb
    )
    np.testing.assert_array_equal(got["intensity"], intensity)
    np.testing.assert_array_equal(got["rowIndex"], scan_i)
    np.testing.assert_array_equal(got["isColorInvalid"], ~coloured)
    from pye57 import libe57

    start = libe57.StructureNode(scan.get("acquisitionStart"))  # type: ignore[attr-defined]
    t0 = libe57.FloatNode(start.get("dateTimeValue")).value()
    np.testing.assert_allclose(got["timeStamp"] + t0, utc_to_gps(utc), atol=1e-6)
    assert wkt.startswith("PROJCS[") and pyproj.CRS(wkt).to_epsg() == 25831
    software = libe57.StringNode(scan.get("sensorSoftwareVersion")).value()  # type: ignore[attr-defined]
    assert software == SOFTWARE
    imf.close()  # type: ignore[attr-defined]


def test_an_aborted_e57_leaves_nothing(tmp_path: Path) -> None:
    out = E57Stream(tmp_path / "c.e57")
    out.write(*_points(10, 0))
    out.abort()
    assert list(tmp_path.iterdir()) == []


def test_colorize_writes_e57_from_the_suffix(tmp_path: Path) -> None:
    truth = write_drive_log(tmp_path, 0.5)
    calib = tmp_path / "calib.yaml"
    calibfile.save(truth.calibration, calib)
    las, e57 = tmp_path / "c.las", tmp_path / "c.e57"
    for out in (las, e57):
        argv = ["colorize", *map(str, truth.files), "--calib", str(calib), "-o", str(out)]
        assert acq_main([*argv, "--no-preview"]) == 0
    got, (imf, _), _ = _read(e57)
    imf.close()  # type: ignore[attr-defined]
    ref = laspy.read(las)
    assert got["cartesianX"].size == len(ref.points) > 0
    np.testing.assert_allclose(got["cartesianX"], ref.x, atol=6e-4)
    np.testing.assert_array_equal(got["isColorInvalid"], 1 - np.asarray(ref.coloured))
