"""The page's packed points (acq.view.points_payload) of clouds written by acq's own PLY and
LAS writers: every attribute read back as written, from PLY, LAS, LAZ and COPC alike, the
subset rule within a range of rows, and foreign files with x y z only."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from acq.cloud.copc import CopcStream
from acq.cloud.las import LasStream
from acq.cloud.ply import PlyStream
from acq.view.points_payload import HEADER, payload, split_payload, subset
from tests.view.layer_files import unpack

FAR = (431_000.0, 4_582_000.0, 12.0)  # a projected CRS's coordinates (m)
UTC0 = 1_764_000_000.0  # 2025-11-24: the drive's first time (UTC s)
CAMERAS = ["left", "right rear"]


def _attributes(n: int, seed: int = 0) -> dict[str, np.ndarray]:
    """A cloud's columns as acq's writers take them, each of known values."""
    rng = np.random.default_rng(seed)
    coloured = rng.integers(0, 2, n).astype(bool)
    return {
        "xyz": rng.uniform(-5, 5, (n, 3)) + np.array(FAR),
        "rgb": rng.integers(0, 256, (n, 3), dtype=np.uint8),
        "time": UTC0 + np.sort(rng.uniform(0, 300, n)),
        # whole numbers: LAS keeps intensity as uint16
        "intensity": rng.integers(0, 4000, n).astype(np.float32),
        "scan": np.arange(n, dtype=np.int32) // 7,
        "coloured": coloured,
        "camera": np.where(coloured, rng.integers(0, 2, n), 255).astype(np.uint8),
        "frame": np.arange(n, dtype=np.int32),
    }


def _write(path: Path, a: dict[str, np.ndarray]) -> Path:
    """``a`` written by acq's writer for ``path``'s suffix (.ply, .las, .laz, .copc.laz)."""
    if path.suffix == ".ply":
        out: PlyStream | LasStream | CopcStream = PlyStream(path, ["frame world"], CAMERAS)
    elif path.name.endswith(".copc.laz"):
        out = CopcStream(path, crs="EPSG:25831", cameras=CAMERAS)
    else:
        out = LasStream(path, crs="EPSG:25831", cameras=CAMERAS)
    columns = ("xyz", "rgb", "time", "intensity", "scan", "coloured", "camera", "frame")
    out.write(*(a[k] for k in columns))
    out.close()
    return path


@pytest.mark.parametrize("name", ["c.ply", "c.las", "c.laz", "c.copc.laz"])
def test_every_attribute_comes_back_as_written(tmp_path: Path, name: str) -> None:
    a = _attributes(3000)
    got = unpack(payload(_write(tmp_path / name, a), 10_000))
    assert (got["shown"], got["rows"], got["start"], got["stop"]) == (3000, 3000, 0, 3000)
    assert got["flags"] == 63 and got["names"] == CAMERAS
    if name.endswith(".copc.laz"):  # COPC reorders the points by its octree: sorted back by time
        order = np.argsort(got["time"], kind="stable")
        got = {k: v[order] if isinstance(v, np.ndarray) else v for k, v in got.items()}
    assert np.abs(got["xyz"] - a["xyz"]).max() < 0.0006  # mm in LAS; float32 offsets < 10 m
    # float32 seconds from the first point's (a double): better than 50 µs over 300 s
    assert np.abs(got["time"].astype(np.float64) + got["time0"] - a["time"]).max() < 5e-5
    assert (got["rgb"] == a["rgb"]).all() and (got["intensity"] == a["intensity"]).all()
    assert (got["scan"] == a["scan"]).all() and (got["coloured"] == a["coloured"]).all()
    assert (got["camera"] == a["camera"]).all()


@pytest.mark.parametrize("name", ["c.ply", "c.laz"])
def test_a_range_of_rows_is_subset_by_the_pages_rule(
    tmp_path: Path, name: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    # many chunks in a small file, the range starting and ending inside them
    monkeypatch.setattr("acq.view.ply_rows._CHUNK_POINTS", 333)
    monkeypatch.setattr("acq.view.las_rows._CHUNK_POINTS", 333)
    a = _attributes(5000)
    path = _write(tmp_path / name, a)
    for start, stop, cap in [(0, 5000, 1234), (1000, 4321, 700), (4999, 5000, 9), (17, 2017, 2000)]:
        got = unpack(payload(path, cap, start, stop))
        rows = subset(start, stop, cap)
        assert got["shown"] == len(rows) == min(cap, stop - start)
        assert rows[0] == start and rows[-1] < stop
        assert (got["start"], got["stop"], got["rows"]) == (start, stop, 5000)
        assert np.abs(got["xyz"] - a["xyz"][rows]).max() < 0.0006
        assert (got["scan"] == a["scan"][rows]).all() and (got["camera"] == a["camera"][rows]).all()
        assert got["time0"] == pytest.approx(a["time"][rows[0]], abs=1e-6)
        assert np.abs(got["time"].astype(np.float64) + got["time0"] - a["time"][rows]).max() < 5e-5


@pytest.mark.parametrize("name", ["c.las", "c.laz", "c.copc.laz"])
def test_a_range_of_rows_is_those_rows_of_the_whole(
    tmp_path: Path, name: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    # a LAZ's rows reached by seeking (a COPC file's are in its octree's order)
    monkeypatch.setattr("acq.view.las_rows._CHUNK_POINTS", 500)
    path = _write(tmp_path / name, _attributes(4000))
    whole = unpack(payload(path, 4000))
    for start, stop, cap in [(2500, 4000, 1500), (1234, 3210, 300)]:
        part = unpack(payload(path, cap, start, stop))
        rows = subset(start, stop, cap)
        assert np.abs(part["xyz"] - whole["xyz"][rows]).max() < 1e-6
        for column in ("rgb", "scan", "intensity", "coloured", "camera"):
            assert (part[column] == whole[column][rows]).all(), column


def test_the_subset_rule() -> None:
    rows = subset(100, 10_100, 3000)
    assert (rows == 100 + np.arange(3000) * 10_000 // 3000).all()
    assert (subset(5, 9, 100) == [5, 6, 7, 8]).all()


@pytest.mark.parametrize("encoding", ["binary_little_endian", "ascii"])
def test_a_foreign_ply_of_x_y_z_only(tmp_path: Path, encoding: str) -> None:
    from plyfile import PlyData, PlyElement

    xyz = np.zeros(50, [("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    xyz["x"] = np.arange(50)
    path = tmp_path / "foreign.ply"
    PlyData([PlyElement.describe(xyz, "vertex")], text=encoding == "ascii").write(str(path))
    got = unpack(payload(path, 20))
    assert got["flags"] == 0 and got["names"] == [] and got["shown"] == 20
    assert (got["xyz"][:, 0] == np.arange(20) * 50 // 20).all()
    assert set(got) == {
        "shown",
        "rows",
        "start",
        "stop",
        "origin",
        "time0",
        "flags",
        "part",
        "names",
        "xyz",
    }
    points, attributes = split_payload(path, 20).points, split_payload(path, 20).attributes
    assert len(points) == 80 + 12 * 20 and len(attributes) == 80  # its header only
    assert set(unpack(points, attributes)) == set(got)


def test_a_las_file_of_another_writer_without_acqs_extra_bytes(tmp_path: Path) -> None:
    import laspy

    header = laspy.LasHeader(point_format=3, version="1.2")  # time and colours, 16-bit
    las = laspy.LasData(header)
    las.x, las.y, las.z = np.arange(10.0), np.zeros(10), np.ones(10)
    las.red, las.green, las.blue = (np.full(10, 65535), np.full(10, 257 * 128), np.zeros(10))
    las.intensity = np.arange(10) * 100
    las.gps_time = 1000.0 + np.arange(10)  # GPS week time: kept as it is
    las.write(tmp_path / "other.las")
    got = unpack(payload(tmp_path / "other.las", 100))
    assert got["flags"] == 1 | 2 | 8 and got["names"] == []
    assert (got["rgb"] == [255, 128, 0]).all() and (got["intensity"] == np.arange(10) * 100).all()
    assert got["time0"] == 1000.0 and (got["time"] == np.arange(10)).all()


@pytest.mark.parametrize("name", ["c.ply", "c.laz"])
def test_the_split_payload_is_the_whole_in_two_parts(tmp_path: Path, name: str) -> None:
    """The first frame's part holds 15 bytes a point (positions and sRGB) after its header,
    the attributes part the other 14 of the same points: together, the whole payload."""
    path = _write(tmp_path / name, _attributes(3000))
    split = split_payload(path, 2000)
    names = -(-len("\n".join(CAMERAS)) // 4) * 4
    assert len(split.points) == HEADER.size + names + 15 * 2000
    assert len(split.attributes) == HEADER.size + names + 14 * 2000
    points, whole = unpack(split.points), unpack(payload(path, 2000))
    assert points["part"] == 64 and points["flags"] == 63  # the attributes the file has
    assert set(points) == {*whole, "rgb"} - {"time", "scan", "intensity", "coloured", "camera"}
    got = unpack(split.points, split.attributes)
    assert got.keys() == whole.keys()
    for key, value in whole.items():
        assert np.array_equal(got[key], value), key


def test_bad_calls_are_refused(tmp_path: Path) -> None:
    path = _write(tmp_path / "c.ply", _attributes(10))
    with pytest.raises(ValueError, match="max_points 0"):
        payload(path, 0)
    for start, stop in [(5, 5), (-1, 3), (0, 11), (7, 2)]:
        with pytest.raises(ValueError, match=rf"rows \[{start}, {stop}\) of a file of 10"):
            payload(path, 10, start, stop)
