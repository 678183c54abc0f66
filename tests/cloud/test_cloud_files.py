"""PLY, LAS and LAZ written part by part (acq.cloud.PlyStream, acq.cloud.las.LasStream),
the format from the output's suffix (acq.cloud.writer.format_of), each point's source
camera and frame passed on by acq.cloud.writer.CloudWriter."""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pytest
from plyfile import PlyData

from acq.cli import main as acq_main
from acq.cloud import PlyStream
from acq.cloud.chunks import ChunkResult
from acq.cloud.las import LasStream
from acq.cloud.report import Report
from acq.cloud.writer import CloudWriter, format_of
from acq.errors import InputValueError
from acq.provenance import made_by_acq


def _points(n: int, seed: int) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(-50, 50, (n, 3)) + np.array([512_345.678, 5_401_234.5, 250.0])
    rgb = rng.integers(0, 256, (n, 3), dtype=np.uint8)
    utc = 1.7e9 + np.sort(rng.uniform(0, 10, n))
    intensity = rng.uniform(0, 4000, n).astype(np.float32)
    scan = np.sort(rng.integers(0, 400, n)).astype(np.uint32)
    coloured = rng.random(n) < 0.6
    # two cameras, left (0) and right (1), each its own frames; 255 and -1 where none
    camera = np.where(coloured, rng.integers(0, 2, n), 255).astype(np.uint8)
    frame = np.where(coloured, rng.integers(0, 3000, n) + 7 * camera, -1).astype(np.int32)
    return xyz, rgb, utc, intensity, scan, coloured, camera, frame


def test_ply_in_parts_reads_back_whole_with_its_counts(tmp_path: Path) -> None:
    parts = [_points(n, seed) for seed, n in enumerate((1000, 0, 2500))]
    out = PlyStream(tmp_path / "c.ply", ["frame world"], ["left", "right"])
    for p in parts:
        out.write(*p)
    size = out.close()
    assert size == (tmp_path / "c.ply").stat().st_size
    assert list(tmp_path.iterdir()) == [tmp_path / "c.ply"]  # no temporary left
    ply = PlyData.read(str(tmp_path / "c.ply"))
    v = ply["vertex"].data
    xyz, rgb, utc, intensity, scan, coloured, camera, frame = (
        np.concatenate(c) for c in zip(*parts, strict=True)
    )
    assert len(v) == 3500
    np.testing.assert_array_equal(np.stack([v["x"], v["y"], v["z"]], axis=1), xyz)
    np.testing.assert_array_equal(np.stack([v["red"], v["green"], v["blue"]], axis=1), rgb)
    np.testing.assert_array_equal(v["scalar_time"], utc)
    np.testing.assert_array_equal(v["intensity"], intensity)
    np.testing.assert_array_equal(v["scalar_scan"], scan)
    np.testing.assert_array_equal(v["scalar_coloured"], coloured)
    np.testing.assert_array_equal(v["scalar_camera"], camera)
    np.testing.assert_array_equal(v["scalar_frame"], frame)
    assert set(np.unique(camera)) == {0, 1, 255}
    assert f"{int(coloured.sum())} of 3500 points coloured" in ply.comments
    assert "frame world" in ply.comments
    assert [c for c in ply.comments if c.startswith("camera ")] == [
        "camera 0 left",
        "camera 1 right",
    ]


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
        "scalar_time", "scalar_scan", "intensity", "scalar_coloured", "scalar_camera",
        "scalar_frame",
    ]  # fmt: skip


def _extra_ranges(las: laspy.LasData) -> dict[str, tuple[int, int | None, int | None]]:
    """Each extra dimension's (options byte, min, max) as the extra-bytes VLR says (None
    where its options bit says it does not hold)."""
    vlr = las.header.vlrs.get("ExtraBytesVlr")[0]
    return {
        eb.name.rstrip(b"\0").decode(): (
            eb.options,
            None if eb.min is None else int(eb.min[0]),
            None if eb.max is None else int(eb.max[0]),
        )
        for eb in vlr.extra_bytes_structs
    }


def _no_data(las: laspy.LasData) -> dict[str, int | None]:
    """Each extra dimension's no_data value as the extra-bytes VLR says."""
    vlr = las.header.vlrs.get("ExtraBytesVlr")[0]
    return {
        eb.name.rstrip(b"\0").decode(): None if eb.no_data is None else int(eb.no_data[0])
        for eb in vlr.extra_bytes_structs
    }


def _camera_names(las: laspy.LasData) -> list[str]:
    """The cameras' names from the acq cameras VLR, as a reader of the file finds them."""
    (vlr,) = [v for v in las.header.vlrs if (v.user_id, v.record_id) == ("acq", 1)]
    lines = vlr.record_data.rstrip(b"\0").decode().splitlines()
    assert [ln.split(" ", 1)[0] for ln in lines] == [str(k) for k in range(len(lines))]
    return [ln.split(" ", 1)[1] for ln in lines]


def _check_camera_and_frame(
    las: laspy.LasData,
    camera: np.ndarray,
    frame: np.ndarray,
    order: slice | np.ndarray = slice(None),
) -> None:
    """``las`` holds ``camera`` and ``frame`` (its points taken in ``order``) with their
    no_data values and true ranges over the points that have one, and names the cameras
    left and right."""
    np.testing.assert_array_equal(np.asarray(las.camera)[order], camera)
    np.testing.assert_array_equal(np.asarray(las.frame)[order], frame)
    assert las.point_format.dimension_by_name("camera").dtype == np.uint8
    assert las.point_format.dimension_by_name("frame").dtype == np.int32
    assert _no_data(las) == {"scan_index": None, "coloured": None, "camera": 255, "frame": -1}
    ranges = _extra_ranges(las)
    assert ranges["camera"][0] & 0b111 == 0b111 and ranges["camera"][1:] == (0, 1)
    valid = frame[frame >= 0]
    assert ranges["frame"][0] & 0b111 == 0b111
    assert ranges["frame"][1:] == (int(valid.min()), int(valid.max()))
    assert _camera_names(las) == ["left", "right"]


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_las_and_laz_carry_true_extra_bytes_ranges_wkt1_and_a_real_system(
    tmp_path: Path, suffix: str
) -> None:
    parts = [_points(n, seed) for seed, n in enumerate((800, 1700))]
    out = LasStream(tmp_path / f"c{suffix}", crs="EPSG:25831", cameras=["left", "right"])
    for p in parts:
        out.write(*p)
    out.close()
    las = laspy.read(tmp_path / f"c{suffix}")
    assert las.header.are_points_compressed == (suffix == ".laz")
    _check_camera_and_frame(
        las, *(np.concatenate([p[k] for p in parts]) for k in (6, 7))
    )  # fmt: skip
    scan = np.concatenate([p[4] for p in parts])
    coloured = np.concatenate([p[5] for p in parts])
    np.testing.assert_array_equal(np.asarray(las.scan_index), scan)
    np.testing.assert_array_equal(np.asarray(las.coloured), coloured)
    ranges = _extra_ranges(las)
    # options bits 1 and 2: min and max hold
    assert ranges["scan_index"][0] & 0b110 == 0b110
    assert ranges["scan_index"][1:] == (int(scan.min()), int(scan.max()))
    assert ranges["coloured"][0] & 0b110 == 0b110 and ranges["coloured"][1:] == (0, 1)
    wkt = las.header.vlrs.get("WktCoordinateSystemVlr")[0].string
    assert wkt.startswith("PROJCS[") and las.header.global_encoding.wkt
    assert las.header.parse_crs().to_epsg() == 25831
    assert las.header.system_identifier == "OTHER"
    assert las.header.generating_software.startswith("acq ")
    assert made_by_acq(tmp_path / f"c{suffix}")


def test_laz_is_compressed_and_smaller_than_las(tmp_path: Path) -> None:
    # a scanner's cloud: neighbours close in space and time (LASzip's case)
    n = 20_000
    t = np.linspace(0, 10, n)
    xyz = np.stack([t * 5, np.sin(t * 50) * 3, np.cos(t * 50) * 3], axis=1) + 500_000
    rgb = np.full((n, 3), 128, dtype=np.uint8)
    scan = (t * 40).astype(np.uint32)
    camera, frame = np.zeros(n, np.uint8), (t * 25).astype(np.int32)
    p = (xyz, rgb, 1.7e9 + t, np.full(n, 100.0, np.float32), scan, np.ones(n, bool), camera, frame)
    sizes = {}
    for suffix in (".las", ".laz"):
        out = LasStream(tmp_path / f"c{suffix}")
        out.write(*p)
        sizes[suffix] = out.close()
    assert sizes[".laz"] < sizes[".las"] / 4, sizes
    las, laz = (laspy.read(tmp_path / f"c{s}") for s in (".las", ".laz"))
    for dim in ("X", "Y", "Z", "gps_time", "red", "scan_index", "coloured", "camera", "frame"):
        np.testing.assert_array_equal(np.asarray(laz[dim]), np.asarray(las[dim]))


def test_an_empty_file_says_its_extra_ranges_do_not_hold(tmp_path: Path) -> None:
    out = LasStream(tmp_path / "e.laz")
    out.close()
    ranges = _extra_ranges(laspy.read(tmp_path / "e.laz"))
    assert ranges and all(r == (r[0] & ~0b110, None, None) for r in ranges.values())


def test_points_no_camera_saw_leave_the_camera_and_frame_ranges_unsaid(tmp_path: Path) -> None:
    xyz, rgb, utc, intensity, scan, _, _, _ = _points(50, 3)
    none = np.zeros(50, bool)
    out = LasStream(tmp_path / "c.las", cameras=["left", "right"])
    out.write(
        xyz, rgb, utc, intensity, scan, none, np.full(50, 255, np.uint8), np.full(50, -1, np.int32)
    )
    out.close()
    ranges = _extra_ranges(laspy.read(tmp_path / "c.las"))
    assert ranges["camera"] == (0b001, None, None) and ranges["frame"] == (0b001, None, None)
    assert ranges["coloured"] == (0b110, 0, 0)


def _result(p: tuple[np.ndarray, ...]) -> ChunkResult:
    """A chunk's result holding the points ``p`` (as :func:`_points` makes them)."""
    xyz, rgb, utc, intensity, scan, coloured, camera, frame = p
    n = xyz.shape[0]
    zeros = np.zeros(n, np.float32)
    return ChunkResult(
        index=0, xyz=xyz, rgb=rgb, coloured=coloured, hidden=np.zeros(n, bool),
        time_ns=np.round((utc - 1.7e9) * 1e9).astype(np.int64), scan=scan,
        step=np.zeros(n, np.uint32), intensity=intensity, dt_s=zeros, theta=zeros,
        camera=camera, frame=frame, scan_origin=np.zeros((0, 3)),
    )  # fmt: skip


@pytest.mark.parametrize("name", ["c.ply", "c.laz"])
def test_the_writer_passes_every_points_camera_and_frame_and_names_the_cameras(
    tmp_path: Path, name: str
) -> None:
    p = _points(400, 5)
    clock = np.array([[0, 1_700_000_000 * 10**9]], np.int64)  # monotonic 0 is that UTC
    out = CloudWriter(tmp_path / name, None, clock, Report(name), ["left", "right"])
    out.write(_result(p))
    out.close()
    if name.endswith(".ply"):
        ply = PlyData.read(str(tmp_path / name))
        v = ply["vertex"].data
        np.testing.assert_array_equal(v["scalar_camera"], p[6])
        np.testing.assert_array_equal(v["scalar_frame"], p[7])
        assert {"camera 0 left", "camera 1 right"} <= set(ply.comments)
    else:
        _check_camera_and_frame(laspy.read(tmp_path / name), p[6], p[7])


def test_the_writer_refuses_a_point_of_a_camera_it_does_not_name(tmp_path: Path) -> None:
    p = list(_points(10, 5))
    p[6][3] = 2  # two cameras named: 0 and 1
    out = CloudWriter(tmp_path / "c.ply", None, np.zeros((1, 2), np.int64), Report("c"), ["a", "b"])
    with pytest.raises(ValueError, match="camera 2 is not one of the 2 the cloud names"):
        out.write(_result(tuple(p)))
    out.stream.abort()
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("cameras", "message"),
    [
        (["left", "right\nx"], r"camera 'right\\nx': .*one line of printable ASCII"),
        (["left", ""], "camera '': "),
        ([f"c{k}" for k in range(256)], "256 cameras: a cloud names at most 255"),
    ],
)
def test_camera_names_a_header_cannot_hold_are_refused_before_anything_is_written(
    tmp_path: Path, cameras: list[str], message: str
) -> None:
    clock = np.zeros((1, 2), np.int64)
    for name in ("c.ply", "c.las", "c.copc.laz", "c.e57"):
        with pytest.raises(InputValueError, match=message):
            CloudWriter(tmp_path / name, None, clock, Report(name), cameras)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("name", "kind"),
    [
        ("a.ply", "ply"),
        ("a.LAS", "las"),
        ("d.x.laz", "laz"),
        ("a.E57", "e57"),
        ("a.COPC.laz", "copc"),
        ("a.copc.las", "las"),
    ],
)
def test_the_format_is_the_suffix(name: str, kind: str) -> None:
    assert format_of(Path(name)) == kind


@pytest.mark.parametrize("name", ["a.xyz", "a", "a.copc", "a.las.gz"])
def test_an_unknown_suffix_is_refused_naming_the_option_before_any_work(
    tmp_path: Path, name: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(
        InputValueError, match=r"^-o .*expected a \.ply, \.las, \.laz, \.copc\.laz, \.e57 file"
    ):
        format_of(Path(name))
    # the log and calibration do not exist: the suffix is refused first
    argv = ["colorize", str(tmp_path / "none.mcap"), "--calib", str(tmp_path / "none.yaml")]
    assert acq_main([*argv, "-o", str(tmp_path / name)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"acq colorize: -o {tmp_path / name}") and err.count("\n") == 1, err
    assert list(tmp_path.iterdir()) == []
