"""PLY and LAS written part by part (acq.cloud.PlyStream, acq.cloud.las.LasStream)."""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pytest
from plyfile import PlyData

from acq.cloud import PlyStream
from acq.cloud.las import LasStream


def _points(n: int, seed: int) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(-50, 50, (n, 3)) + np.array([512_345.678, 5_401_234.5, 250.0])
    rgb = rng.integers(0, 256, (n, 3), dtype=np.uint8)
    utc = 1.7e9 + np.sort(rng.uniform(0, 10, n))
    intensity = rng.uniform(0, 4000, n).astype(np.float32)
    scan = np.sort(rng.integers(0, 400, n)).astype(np.uint32)
    coloured = rng.random(n) < 0.6
    return xyz, rgb, utc, intensity, scan, coloured


def test_ply_in_parts_reads_back_whole_with_its_counts(tmp_path: Path) -> None:
    parts = [_points(n, seed) for seed, n in enumerate((1000, 0, 2500))]
    out = PlyStream(tmp_path / "c.ply", ["frame world"])
    for p in parts:
        out.write(*p)
    size = out.close()
    assert size == (tmp_path / "c.ply").stat().st_size and not (tmp_path / "c.ply.tmp").exists()
    ply = PlyData.read(str(tmp_path / "c.ply"))
    v = ply["vertex"].data
    xyz, rgb, utc, intensity, scan, coloured = (np.concatenate(c) for c in zip(*parts, strict=True))
    assert len(v) == 3500
    np.testing.assert_array_equal(np.stack([v["x"], v["y"], v["z"]], axis=1), xyz)
    np.testing.assert_array_equal(np.stack([v["red"], v["green"], v["blue"]], axis=1), rgb)
    np.testing.assert_array_equal(v["scalar_time"], utc)
    np.testing.assert_array_equal(v["intensity"], intensity)
    np.testing.assert_array_equal(v["scalar_scan"], scan)
    np.testing.assert_array_equal(v["scalar_coloured"], coloured)
    assert f"{int(coloured.sum())} of 3500 points coloured" in ply.comments
    assert "frame world" in ply.comments


def test_an_aborted_file_leaves_nothing(tmp_path: Path) -> None:
    for out in (PlyStream(tmp_path / "c.ply"), LasStream(tmp_path / "c.las")):
        out.write(*_points(10, 0))
        out.abort()
    assert list(tmp_path.iterdir()) == []


def test_las_in_parts_keeps_millimetres_and_grows_its_header(tmp_path: Path) -> None:
    parts = [_points(n, seed) for seed, n in enumerate((800, 1700))]
    out = LasStream(tmp_path / "c.las", crs="EPSG:25832", comments=["frame world"])
    for p in parts:
        out.write(*p)
    out.close()
    las = laspy.read(tmp_path / "c.las")
    xyz = np.concatenate([p[0] for p in parts])
    assert las.header.point_count == 2500
    np.testing.assert_array_equal(las.header.offsets, np.floor(parts[0][0].min(axis=0)))
    got = np.stack([las.x, las.y, las.z], axis=1)
    assert np.abs(got - xyz).max() <= 0.0005 + 1e-9
    np.testing.assert_allclose(las.header.mins, xyz.min(axis=0), atol=0.0006)
    np.testing.assert_allclose(las.header.maxs, xyz.max(axis=0), atol=0.0006)
    assert las.header.parse_crs().to_epsg() == 25832
    np.testing.assert_array_equal(np.asarray(las.scan_index), np.concatenate([p[4] for p in parts]))


def test_an_empty_las_is_still_a_las(tmp_path: Path) -> None:
    out = LasStream(tmp_path / "e.las")
    out.close()
    assert laspy.read(tmp_path / "e.las").header.point_count == 0


@pytest.mark.parametrize("bad", ["EPSG:0", "not a crs"])
def test_a_bad_crs_is_refused_before_anything_is_written(tmp_path: Path, bad: str) -> None:
    import pyproj

    with pytest.raises(pyproj.exceptions.CRSError):
        LasStream(tmp_path / "c.las", crs=bad)
    assert list(tmp_path.iterdir()) == []


def test_ply_header_holds_only_types_and_names_every_common_reader_keeps(tmp_path: Path) -> None:
    # Open3D's tensor reader skips char, short and uint properties; CloudCompare imports a
    # property as a scalar field only when its name holds "scalar" (or is intensity)
    out = PlyStream(tmp_path / "c.ply")
    out.write(*_points(3, 0))
    out.close()
    ply = PlyData.read(str(tmp_path / "c.ply"))
    assert (
        ply.text is False and ply.byte_order == "<" and [e.name for e in ply.elements] == ["vertex"]
    )
    props = [(p.name, p.val_dtype) for p in ply["vertex"].properties]
    kept = {"u1", "u2", "i4", "f4", "f8"}
    assert all(dtype.lstrip("<>=|") in kept for _, dtype in props), props
    standard = {"x", "y", "z", "red", "green", "blue", "intensity"}
    assert all(name in standard or name.startswith("scalar_") for name, _ in props), props
    assert [name for name, _ in props] == [
        "x", "y", "z", "red", "green", "blue",
        "scalar_time", "scalar_scan", "intensity", "scalar_coloured",
    ]  # fmt: skip
