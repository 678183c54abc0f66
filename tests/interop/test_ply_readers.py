"""acq's PLY opened by the readers users open it with (CloudCompare, Open3D's tensor and
legacy APIs, PCL, trimesh, plyfile): every per-point field comes back with its values.
Run by `make interop` (installs the `interop` extra); a reader not installed is skipped."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from plyfile import PlyData

from acq.cloud import PlyStream

pytestmark = pytest.mark.interop

N = 500


class Written:
    def __init__(self, path: Path) -> None:
        rng = np.random.default_rng(7)
        self.path = path
        self.xyz = rng.uniform(-50, 50, (N, 3)) + np.array([512_345.678, 5_401_234.5, 250.0])
        self.rgb = rng.integers(0, 256, (N, 3), dtype=np.uint8)
        self.time = 1.7e9 + np.sort(rng.uniform(0, 60, N))  # UTC s, sub-microsecond steps
        self.intensity = rng.uniform(0, 4000, N).astype(np.float32)
        self.scan = np.sort(rng.integers(0, 100_000, N)).astype(np.uint32)
        self.coloured = rng.random(N) < 0.6
        # two cameras (0 left, 1 right), 255 and -1 where none
        self.camera = np.where(self.coloured, rng.integers(0, 2, N), 255).astype(np.uint8)
        self.frame = np.where(self.coloured, rng.integers(0, 90_000, N), -1).astype(np.int32)
        out = PlyStream(path, ["frame world"], ["left", "right"])
        out.write(self.xyz, self.rgb, self.time, self.intensity, self.scan, self.coloured,
                  self.camera, self.frame)  # fmt: skip
        out.close()


@pytest.fixture
def cloud(tmp_path: Path) -> Written:
    return Written(tmp_path / "c.ply")


def test_plyfile_reads_every_field_and_the_cameras_names(cloud: Written) -> None:
    ply = PlyData.read(str(cloud.path))
    assert {"camera 0 left", "camera 1 right"} <= set(ply.comments)
    v = ply["vertex"].data
    np.testing.assert_array_equal(np.stack([v["x"], v["y"], v["z"]], 1), cloud.xyz)
    np.testing.assert_array_equal(np.stack([v["red"], v["green"], v["blue"]], 1), cloud.rgb)
    np.testing.assert_array_equal(v["scalar_time"], cloud.time)
    np.testing.assert_array_equal(v["scalar_scan"], cloud.scan)
    np.testing.assert_array_equal(v["intensity"], cloud.intensity)
    np.testing.assert_array_equal(v["scalar_coloured"], cloud.coloured)
    np.testing.assert_array_equal(v["scalar_camera"], cloud.camera)
    np.testing.assert_array_equal(v["scalar_frame"], cloud.frame)


def test_open3d_tensor_api_keeps_every_field(cloud: Written) -> None:
    o3d = pytest.importorskip("open3d")
    pc = o3d.t.io.read_point_cloud(str(cloud.path))
    attr = {k: pc.point[k].numpy() for k in pc.point}
    assert set(attr) == {
        "positions", "colors", "scalar_time", "scalar_scan", "intensity", "scalar_coloured",
        "scalar_camera", "scalar_frame",
    }  # fmt: skip
    np.testing.assert_array_equal(attr["positions"], cloud.xyz)
    np.testing.assert_array_equal(attr["colors"], cloud.rgb)
    np.testing.assert_array_equal(attr["scalar_time"][:, 0], cloud.time)
    np.testing.assert_array_equal(attr["scalar_scan"][:, 0], cloud.scan)
    np.testing.assert_array_equal(attr["intensity"][:, 0], cloud.intensity)
    np.testing.assert_array_equal(attr["scalar_coloured"][:, 0], cloud.coloured)
    np.testing.assert_array_equal(attr["scalar_camera"][:, 0], cloud.camera)
    np.testing.assert_array_equal(attr["scalar_frame"][:, 0], cloud.frame)


def test_open3d_legacy_api_keeps_points_and_colours(cloud: Written) -> None:
    o3d = pytest.importorskip("open3d")
    pc = o3d.io.read_point_cloud(str(cloud.path))
    np.testing.assert_array_equal(np.asarray(pc.points), cloud.xyz)
    np.testing.assert_allclose(np.asarray(pc.colors) * 255, cloud.rgb, atol=1e-9)


def test_trimesh_keeps_every_field(cloud: Written) -> None:
    trimesh = pytest.importorskip("trimesh")
    pc = trimesh.load(str(cloud.path))
    assert isinstance(pc, trimesh.PointCloud)
    np.testing.assert_array_equal(pc.vertices, cloud.xyz)
    np.testing.assert_array_equal(pc.colors[:, :3], cloud.rgb)
    v = pc.metadata["_ply_raw"]["vertex"]["data"]
    np.testing.assert_array_equal(v["scalar_time"], cloud.time)
    np.testing.assert_array_equal(v["scalar_scan"], cloud.scan)
    np.testing.assert_array_equal(v["intensity"], cloud.intensity)
    np.testing.assert_array_equal(v["scalar_coloured"], cloud.coloured)
    np.testing.assert_array_equal(v["scalar_camera"], cloud.camera)
    np.testing.assert_array_equal(v["scalar_frame"], cloud.frame)


def _pcd(path: Path) -> np.ndarray:
    """A binary PCD's points as a structured array (``rgb`` as the uint32 0x00RRGGBB that
    PCL packs into a float)."""
    data = path.read_bytes()
    head, body = data.split(b"DATA binary\n", 1)
    meta = {ln.split()[0]: ln.split()[1:] for ln in head.decode().splitlines() if ln[:1] != "#"}
    kinds = {"F": "f", "U": "u", "I": "i"}
    dtype = np.dtype(
        [(name, "<u4" if name == "rgb" else f"<{kinds[t]}{s}") for name, s, t in zip(
            meta["FIELDS"], meta["SIZE"], meta["TYPE"], strict=True)]
    )  # fmt: skip
    assert all(c == "1" for c in meta["COUNT"])
    return np.frombuffer(body, dtype, int(meta["POINTS"][0]))


def test_pcl_keeps_every_field(cloud: Written, tmp_path: Path) -> None:
    tool = shutil.which("pcl_ply2pcd")
    if tool is None:
        pytest.skip("PCL's pcl_ply2pcd not installed (Debian: pcl-tools)")
    pcd = tmp_path / "c.pcd"
    subprocess.run([tool, "-format", "1", str(cloud.path), str(pcd)], check=True,
                   capture_output=True, timeout=60)  # fmt: skip
    v = _pcd(pcd)
    np.testing.assert_array_equal(np.stack([v["x"], v["y"], v["z"]], 1), cloud.xyz)
    rgb = v["rgb"]
    np.testing.assert_array_equal(np.stack([rgb >> 16, rgb >> 8, rgb], 1) & 0xFF, cloud.rgb)
    np.testing.assert_array_equal(v["scalar_time"], cloud.time)
    np.testing.assert_array_equal(v["scalar_scan"], cloud.scan)
    np.testing.assert_array_equal(v["intensity"], cloud.intensity)
    np.testing.assert_array_equal(v["scalar_coloured"], cloud.coloured)
    np.testing.assert_array_equal(v["scalar_camera"], cloud.camera)
    np.testing.assert_array_equal(v["scalar_frame"], cloud.frame)


def test_cloudcompare_keeps_every_field_as_a_scalar_field(cloud: Written, tmp_path: Path) -> None:
    cc, xvfb = shutil.which("CloudCompare"), shutil.which("xvfb-run")
    if cc is None or xvfb is None:
        pytest.skip("CloudCompare or xvfb-run not installed (Debian: cloudcompare, xvfb)")
    asc = tmp_path / "c.asc"
    cmd = [xvfb, "-a", cc, "-SILENT", "-AUTO_SAVE", "OFF", "-O", "-GLOBAL_SHIFT", "AUTO",
           str(cloud.path), "-C_EXPORT_FMT", "ASC", "-PREC", "12", "-SEP", "SPACE",
           "-ADD_HEADER", "-SAVE_CLOUDS", "FILE", str(asc)]  # fmt: skip
    subprocess.run(cmd, check=True, capture_output=True, timeout=120)
    lines = asc.read_text().splitlines()
    names = lines[0].lstrip("/").split()
    # CloudCompare drops the scalar_ prefix, as it adds it when it writes PLY
    assert names == ["X", "Y", "Z", "R", "G", "B", "time", "scan", "intensity", "coloured",
                     "camera", "frame"]  # fmt: skip
    v = dict(zip(names, np.loadtxt(lines[1:], ndmin=2).T, strict=True))
    # shifted by CloudCompare's global shift, then kept as float32 near the origin
    np.testing.assert_allclose(np.stack([v["X"], v["Y"], v["Z"]], 1), cloud.xyz, atol=1e-4)
    np.testing.assert_array_equal(np.stack([v["R"], v["G"], v["B"]], 1), cloud.rgb)
    np.testing.assert_array_equal(v["scan"], cloud.scan)
    np.testing.assert_allclose(v["intensity"], cloud.intensity, rtol=1e-7)
    np.testing.assert_array_equal(v["coloured"], cloud.coloured)
    np.testing.assert_array_equal(v["camera"], cloud.camera)
    np.testing.assert_array_equal(v["frame"], cloud.frame)  # exact in float32 below 2**24
    # scalar fields are float32 in CloudCompare 2.11 (2.13 adds an offset): 128 s steps
    # at today's UTC seconds, so time is kept to the float32 nearest
    np.testing.assert_array_equal(v["time"], cloud.time.astype(np.float32))
