"""COPC written with copclib (acq.cloud.copc.CopcStream), read back with laspy's
CopcReader by level and by bounds."""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pytest
from laspy.copc import Bounds

from acq.camera import calibfile
from acq.cli import main as acq_main
from acq.cloud import octree
from acq.cloud.copc import CopcStream
from acq.provenance import made_by_acq
from acq.sim.drive_log import write_drive_log
from acq.time.gpstime import gps_adjusted_standard_time
from tests.cloud.test_cloud_files import _check_camera_and_frame, _extra_ranges, _points


def _sorted(t: np.ndarray, *cols: np.ndarray) -> tuple[np.ndarray, ...]:
    """``cols`` in the order of the times ``t`` (distinct here)."""
    order = np.argsort(t)
    return tuple(c[order] for c in cols)


def test_copc_by_level_and_by_bounds(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(octree, "NODE_POINTS", 500)  # a few levels from a few points
    parts = [_points(n, seed) for seed, n in enumerate((3000, 0, 5000))]
    out = CopcStream(tmp_path / "c.copc.laz", crs="EPSG:25831", cameras=["left", "right"])
    for p in parts:
        out.write(*p)
    out.close()
    xyz, rgb, utc, _, scan, coloured, camera, frame = (
        np.concatenate(c) for c in zip(*parts, strict=True)
    )
    path = tmp_path / "c.copc.laz"
    with laspy.CopcReader.open(path) as r:
        assert r.header.point_count == 8000
        root = r.query(level=0)
        assert len(root) == 500
        every = r.query()
        box = Bounds(mins=xyz.min(axis=0), maxs=xyz.min(axis=0) + np.array([40.0, 40.0, 200.0]))
        inside = r.query(bounds=box)
    got = np.stack([every.x, every.y, every.z], axis=1)
    gps = np.asarray(every.gps_time)
    g = _sorted(gps, got, np.asarray(every.scan_index), np.asarray(every.coloured), gps,
                np.asarray(every.red) // 257)  # fmt: skip
    want_gps = gps_adjusted_standard_time(utc)
    w = _sorted(want_gps, xyz, scan, coloured.astype(np.uint8), want_gps, rgb[:, 0])
    assert np.abs(g[0] - w[0]).max() <= 0.0005 + 1e-9
    for a, b in zip(g[1:], w[1:], strict=True):
        np.testing.assert_allclose(a, b, atol=1e-6)
    near = np.all((xyz >= box.mins) & (xyz <= box.maxs), axis=1)
    assert len(inside) == int(near.sum()) > 0
    las = laspy.read(path)  # the whole file, as a LAZ reader sees it
    assert las.header.parse_crs().to_epsg() == 25831
    assert las.header.system_identifier == "OTHER" and made_by_acq(path)
    ranges = _extra_ranges(las)
    assert ranges["scan_index"][1:] == (int(scan.min()), int(scan.max()))
    assert ranges["coloured"][1:] == (0, 1)
    # the file's points are in octree order: compared in time order
    order = np.argsort(np.asarray(las.gps_time))
    want = np.argsort(utc)
    _check_camera_and_frame(las, camera[want], frame[want], order)


def test_copc_without_cameras_keeps_its_padding(tmp_path: Path) -> None:
    out = CopcStream(tmp_path / "c.copc.laz")
    out.write(*_points(100, 1))
    out.close()
    las = laspy.read(tmp_path / "c.copc.laz")
    acq = [(v.record_id, v.description) for v in las.header.vlrs if v.user_id == "acq"]
    assert acq == [(0, "padding")]


def test_colorize_writes_copc_from_the_suffix(tmp_path: Path) -> None:
    truth = write_drive_log(tmp_path, 0.5)
    calib = tmp_path / "calib.yaml"
    calibfile.save(truth.calibration, calib)
    out = tmp_path / "c.copc.laz"
    argv = ["colorize", *map(str, truth.files), "--calib", str(calib), "-o", str(out)]
    assert acq_main([*argv, "--no-preview"]) == 0
    with laspy.CopcReader.open(out) as r:
        assert r.header.point_count == len(r.query()) > 0
