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
from tests.cloud.test_cloud_files import _camera_names, _points

_TYPES = {
    "cartesianX": "d", "cartesianY": "d", "cartesianZ": "d", "timeStamp": "d",
    "intensity": "f", "colorRed": "B", "colorGreen": "B", "colorBlue": "B",
    "isColorInvalid": "B", "rowIndex": "q", "acq:camera": "B", "acq:frame": "q",
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
    out = E57Stream(
        tmp_path / "c.e57", crs="EPSG:25831", comments=["frame world"], cameras=["left", "right"]
    )
    for p in parts:
        out.write(*p)
    size = out.close()
    assert size == (tmp_path / "c.e57").stat().st_size
    assert list(tmp_path.iterdir()) == [tmp_path / "c.e57"]  # no temporary left
    got, (imf, scan), wkt = _read(tmp_path / "c.e57")
    xyz, rgb, utc, intensity, scan_i, coloured, camera, frame = (
        np.concatenate(c) for c in zip(*parts, strict=True)
    )
    np.testing.assert_array_equal(np.stack([got[f"cartesian{a}"] for a in "XYZ"], axis=1), xyz)
    np.testing.assert_array_equal(
        np.stack([got[f"color{c}"] for c in ("Red", "Green", "Blue")], 1), rgb
    )
    np.testing.assert_array_equal(got["intensity"], intensity)
    np.testing.assert_array_equal(got["rowIndex"], scan_i)
    np.testing.assert_array_equal(got["isColorInvalid"], ~coloured)
    np.testing.assert_array_equal(got["acq:camera"], camera)
    np.testing.assert_array_equal(got["acq:frame"], frame)
    from pye57 import libe57

    assert _camera_names_e57(scan) == ["left", "right"]
    description = libe57.StringNode(scan.get("description")).value()  # type: ignore[attr-defined]
    assert description == "frame world; camera 0 left; camera 1 right"
    start = libe57.StructureNode(scan.get("acquisitionStart"))  # type: ignore[attr-defined]
    t0 = libe57.FloatNode(start.get("dateTimeValue")).value()
    np.testing.assert_allclose(got["timeStamp"] + t0, utc_to_gps(utc), atol=1e-6)
    assert wkt.startswith("PROJCS[") and pyproj.CRS(wkt).to_epsg() == 25831
    software = libe57.StringNode(scan.get("sensorSoftwareVersion")).value()  # type: ignore[attr-defined]
    assert software == SOFTWARE
    imf.close()  # type: ignore[attr-defined]


def _camera_names_e57(scan: object) -> list[str]:
    """The scan's acq:cameras, as a reader of the file finds them."""
    from pye57 import libe57

    names = libe57.VectorNode(scan.get("acq:cameras"))  # type: ignore[attr-defined]
    return [libe57.StringNode(names.get(k)).value() for k in range(names.childCount())]


def test_pye57_still_reads_the_points_and_skips_the_extension(tmp_path: Path) -> None:
    import pye57

    p = _points(300, 2)
    out = E57Stream(tmp_path / "c.e57", cameras=["left", "right"])
    out.write(*p)
    out.close()
    # ignore_missing_fields: the file has no cartesianInvalidState (every point is valid)
    data = pye57.E57(str(tmp_path / "c.e57")).read_scan(
        0, colors=True, intensity=True, ignore_missing_fields=True
    )
    np.testing.assert_array_equal(data["cartesianX"], p[0][:, 0])
    np.testing.assert_array_equal(data["colorRed"], p[1][:, 0])


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
    got, (imf, scan), _ = _read(e57)
    names = _camera_names_e57(scan)
    imf.close()  # type: ignore[attr-defined]
    ref = laspy.read(las)
    assert got["cartesianX"].size == len(ref.points) > 0
    np.testing.assert_allclose(got["cartesianX"], ref.x, atol=6e-4)
    np.testing.assert_array_equal(got["isColorInvalid"], 1 - np.asarray(ref.coloured))
    # the one camera of the calibration names index 0, the camera of every coloured point
    assert names == _camera_names(ref) == list(truth.calibration.cameras)
    camera, frame = np.asarray(ref.camera), np.asarray(ref.frame)
    np.testing.assert_array_equal(camera, np.where(ref.coloured, 0, 255))
    assert (frame[camera == 0] >= 0).all() and (frame[camera == 255] == -1).all()
    assert np.unique(frame[camera == 0]).size > 1
    np.testing.assert_array_equal(got["acq:camera"], camera)
    np.testing.assert_array_equal(got["acq:frame"], frame)
