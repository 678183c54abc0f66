"""acq mesh on the short simulated drive (a real MCAP log and calib.yaml): each format
read back by other readers, the vertices coloured as acq colorize colours the same
points, tiles along the track, the seam between chunks, provenance and refused outputs,
option errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pygltflib
import pytest
import trimesh
from plyfile import PlyData

from acq.cli import main as acq_main
from acq.mesh import files
from acq.mesh.files import Y_UP
from acq.provenance import made_by_acq
from acq.sim.drive_log import DriveTruth

Drive = tuple[DriveTruth, Path]


def _mesh(drive: Drive, out: Path, *argv: str) -> int:
    truth, calib = drive
    return acq_main(["mesh", *map(str, truth.files), "--calib", str(calib), "-o", str(out),
                     *argv])  # fmt: skip


def _ply(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(xyz, rgb, faces) of a mesh PLY, read by plyfile."""
    data = PlyData.read(str(path))
    v = data["vertex"].data
    xyz = np.stack([v["x"], v["y"], v["z"]], axis=1)
    rgb = np.stack([v["red"], v["green"], v["blue"]], axis=1)
    return xyz, rgb, np.stack(data["face"].data["vertex_indices"]).astype(np.int64)


def _triangles(xyz: np.ndarray, faces: np.ndarray) -> set[bytes]:
    """Each facet as the bytes of its three vertices' coordinates, in a fixed order."""
    corners = np.sort(xyz[faces].view([("x", "f8"), ("y", "f8"), ("z", "f8")])[..., 0], axis=1)
    return {t.tobytes() for t in corners}


@pytest.fixture(scope="module")
def whole(short_drive: Drive, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The short drive's mesh as one PLY (its 11 m under one tile), in one chunk."""
    out = tmp_path_factory.mktemp("mesh") / "m.ply"
    assert _mesh(short_drive, out) == 0
    return out


def test_vertices_have_the_coloured_clouds_colours(
    short_drive: Drive, whole: Path, tmp_path: Path
) -> None:
    cloud = tmp_path / "c.ply"
    truth, calib = short_drive
    assert acq_main(["colorize", *map(str, truth.files), "--calib", str(calib), "-o",
                     str(cloud), "--no-preview"]) == 0  # fmt: skip
    c = PlyData.read(str(cloud))["vertex"].data
    head = whole.read_bytes()[:2000].split(b"end_header")[0].decode()
    assert "format binary_little_endian 1.0" in head and "element face" in head
    assert "property double x" in head and "property uchar red" in head
    xyz, rgb, faces = _ply(whole)
    assert faces.shape[0] > 1.5 * xyz.shape[0]  # a grid: about two facets per vertex
    assert np.unique(faces).size == xyz.shape[0]  # every vertex in a facet
    at = {p.tobytes(): k for k, p in enumerate(np.stack([c["x"], c["y"], c["z"]], 1))}
    k = np.array([at[p.tobytes()] for p in xyz])  # every vertex is a point of the cloud
    assert np.array_equal(rgb, np.stack([c["red"], c["green"], c["blue"]], 1)[k])
    assert 0.2 < c["scalar_coloured"][k].mean() < 0.9  # the camera looks to one side
    # a facet joins neighbours of the grid: two consecutive scans
    assert (np.ptp(c["scalar_scan"][k][faces], axis=1) == 1).all()


def test_glb_colours_are_linear_as_gltf_has_them_and_come_back_exactly() -> None:
    """glTF's COLOR_0 is linear: sRGB 128 is 21.6 % of full scale (55.4 % would show paler
    in every viewer); 16 bits give every one of sRGB's 256 levels back."""
    levels = np.arange(256, dtype=np.uint8)
    rgb = np.stack([levels, levels[::-1], np.full(256, 128, np.uint8)], axis=1)
    values = files.gltf_colours(rgb)
    assert values.dtype == np.uint16 and (values[:, 3] == 65535).all()
    assert values[128, 0] / 65535 == pytest.approx(0.2158605, abs=1e-5)
    assert (values[0, :1] == 0).all() and values[255, 0] == 65535
    assert np.array_equal(files.srgb_of_gltf(values), rgb)


def test_glb_and_obj_read_back_as_the_ply(whole: Path, short_drive: Drive, tmp_path: Path) -> None:
    xyz, rgb, faces = _ply(whole)
    glb, obj = tmp_path / "m.glb", tmp_path / "m.obj"
    for out in (glb, obj):
        assert _mesh(short_drive, out) == 0
    g = trimesh.load(glb).to_geometry()  # the node's matrix applied: glTF's +y up
    assert np.abs(g.vertices @ Y_UP - xyz).max() < 1e-3  # float32 about the first vertex
    assert np.array_equal(g.faces, faces)
    assert np.array_equal(files.glb_colours(glb), rgb)  # linear in the file, as glTF has it
    gl = pygltflib.GLTF2().load(str(glb))
    assert gl.asset.version == "2.0" and gl.asset.generator.startswith("acq ")
    prim = gl.meshes[0].primitives[0]
    assert prim.attributes.COLOR_0 is not None and prim.mode == pygltflib.TRIANGLES
    assert gl.accessors[prim.attributes.POSITION].count == xyz.shape[0]
    assert gl.accessors[prim.indices].count == faces.size
    o = trimesh.load(obj, process=False)
    assert np.abs(o.vertices - xyz).max() <= 5e-5  # four decimals
    assert np.array_equal(o.faces, faces)
    assert np.array_equal(o.visual.vertex_colors[:, :3], rgb)
    assert obj.read_text().startswith("# acq ")


def test_tiles_split_by_distance_and_chunks_lose_no_facet(
    whole: Path, short_drive: Drive, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    xyz, _, faces = _ply(whole)
    out = tmp_path / "t.ply"
    # 2 s (11 m) in two chunks of 1 s, in 3 m tiles: four files, the last 2 m
    assert _mesh(short_drive, out, "--tile-m", "3", "--chunk", "1") == 0
    tiles = sorted(tmp_path.glob("t_*.ply"))
    assert [p.name for p in tiles] == [f"t_{k:03d}.ply" for k in range(4)] and not out.exists()
    seen: set[bytes] = set()
    starts = []
    for p in tiles:
        t_xyz, _, t_faces = _ply(p)
        assert np.unique(t_faces).size == t_xyz.shape[0]  # each file whole on its own
        mine = _triangles(t_xyz, t_faces)
        assert len(mine) == t_faces.shape[0] and not mine & seen  # no facet twice
        seen |= mine
        starts.append(t_xyz[:, 0].min())
        assert made_by_acq(p)
    assert seen == _triangles(xyz, faces)  # none lost at a tile's or a chunk's seam
    # the drive goes along +x: each tile begins about 3 m after the one before
    assert np.allclose(np.diff(starts), 3.0, atol=0.5)
    # cut otherwise, the earlier run's tiles are kept and named
    assert _mesh(short_drive, out, "--tile-m", "4") == 0
    said = capsys.readouterr().out
    assert "earlier run with other tiles are still there, not replaced: t_003.ply\n" in said
    assert (tmp_path / "t_003.ply").exists() and not out.exists()


def test_outputs_marked_refused_and_forced(
    short_drive: Drive, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for name in ("m.glb", "m.obj"):
        out = tmp_path / name
        assert _mesh(short_drive, out) == 0 and made_by_acq(out)
        before = out.stat().st_mtime_ns
        assert _mesh(short_drive, out) == 0  # its own earlier output: replaced
        assert out.stat().st_mtime_ns >= before
        out.write_text("someone's notes\n")
        assert _mesh(short_drive, out) == 2
        err = capsys.readouterr().err
        assert "was not written by acq; --force" in err and err.count("\n") == 1, err
        assert out.read_text() == "someone's notes\n"
        assert _mesh(short_drive, out, "--force") == 0 and made_by_acq(out)
    # a tile's name taken by someone else's file: refused before anything is written
    other = tmp_path / "t_001.glb"
    other.write_bytes(b"glTF\x02\x00\x00\x00 someone's model")
    assert _mesh(short_drive, tmp_path / "t.glb", "--tile-m", "3") == 2
    assert "t_001.glb: exists and was not written by acq" in capsys.readouterr().err
    assert not (tmp_path / "t_000.glb").exists() and other.read_bytes().startswith(b"glTF")
    pic = tmp_path / "p.ply"
    pic.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(20))
    assert _mesh(short_drive, pic, "--force") == 2
    assert "is a PNG image, not a mesh" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "expect"),
    [
        (["--tile-m", "nan"], "--tile-m: expected metres in [1, 1000000], got 'nan'"),
        (["--tile-m", "-5"], "--tile-m: expected metres"),
        (["--max-grazing-deg", "90"], "--max-grazing-deg: expected degrees in [0, 90)"),
        (["--edge-a-m", "-0.1"], "--edge-a-m: expected metres"),
        (["--edge-b", "inf"], "--edge-b: expected a ratio"),
        (["--crs", "EPSG:4326"], "--crs EPSG:4326: not a projected CRS"),
        (["--frame", "laser", "--crs", "EPSG:25831"], "the laser frame"),
        (["--crs", "EPSG:25831"], "local coordinates"),  # CAN odometry only
    ],
)
def test_bad_options_are_one_line_and_exit_2(
    short_drive: Drive, tmp_path: Path, capsys: pytest.CaptureFixture[str],
    argv: list[str], expect: str,
) -> None:  # fmt: skip
    assert _mesh(short_drive, tmp_path / "m.glb", *argv) == 2
    err = capsys.readouterr().err
    assert expect in err and err.count("\n") == 1 and err.startswith("acq mesh"), err
    assert list(tmp_path.iterdir()) == []


def test_bad_inputs_are_one_line_and_exit_2(
    short_drive: Drive, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from mcap.writer import Writer

    assert _mesh(short_drive, tmp_path / "m.stl") == 2
    assert "-o " in (err := capsys.readouterr().err) and "expected a .ply, .glb, .obj" in err
    empty = tmp_path / "empty.mcap"
    with empty.open("wb") as f:  # a log without any message
        w = Writer(f)
        w.start()
        w.finish()
    _, calib = short_drive
    argv = ["mesh", str(empty), "--calib", str(calib), "-o", str(tmp_path / "e.glb")]
    assert acq_main(argv) == 2
    err = capsys.readouterr().err
    assert "no laser scanner in the log" in err and err.count("\n") == 1, err
    assert not (tmp_path / "e.glb").exists()


def test_the_laser_frame_is_refused_and_progress_shows_a_bar(
    short_drive: Drive, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "l.ply"
    assert _mesh(short_drive, out, "--frame", "laser") == 2
    err = capsys.readouterr().err
    assert "--frame laser: facets join neighbouring profiles" in err and err.count("\n") == 1
    assert not out.exists()
    assert _mesh(short_drive, out, "--progress") == 0
    assert "colouring" in capsys.readouterr().err


def test_a_tile_is_made_and_written_while_the_next_chunk_is_joined(
    short_drive: Drive, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A tile's atlas is made and its file written on the writer thread: the first
    tile's write waits, here, for the second chunk's facets to begin (it would wait in
    vain on the main thread); the files are those made without waiting."""
    import threading

    from acq.mesh import drive, files, texture

    plain = tmp_path / "plain"
    plain.mkdir()
    argv = ("--tile-m", "3", "--texture", "--chunk", "1")
    assert _mesh(short_drive, plain / "t.glb", *argv) == 0
    real_write, real_build, real_grid = files.write, texture.build_atlas, drive.grid_facets
    second_chunk, writes, builds, grids = threading.Event(), [], [], []

    def write(path: Path, *args: object, **kwargs: object) -> int:
        writes.append(threading.current_thread().name)
        if len(writes) == 1:
            second_chunk.wait(timeout=10)
        return real_write(path, *args, **kwargs)  # type: ignore[arg-type]

    def build_atlas(*args: object) -> texture.Atlas:
        builds.append(threading.current_thread().name)
        return real_build(*args)  # type: ignore[arg-type]

    def grid_facets(*args: object) -> np.ndarray:
        grids.append(1)
        if len(grids) == 2:
            second_chunk.set()
        return real_grid(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(files, "write", write)
    monkeypatch.setattr(texture, "build_atlas", build_atlas)
    monkeypatch.setattr(drive, "grid_facets", grid_facets)
    out = tmp_path / "t.glb"
    assert _mesh(short_drive, out, *argv) == 0
    assert second_chunk.is_set() and len(writes) == len(builds) >= 3
    assert all(t.startswith("acq-mesh-write") for t in writes + builds)
    made = sorted(p.name for p in tmp_path.glob("t_*.glb"))
    assert made == sorted(p.name for p in plain.glob("t_*.glb"))
    assert all((tmp_path / m).read_bytes() == (plain / m).read_bytes() for m in made)


def test_two_tiles_are_made_at_once_and_the_files_are_one_writers(
    short_drive: Drive, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    """With two writer threads the second tile's atlas is made while the first tile is
    still being written; the files and the report's counts are those of one writer."""
    import threading

    from acq.mesh import drive, files, texture

    assert drive.WRITERS == 2
    argv = ("--tile-m", "3", "--texture", "--chunk", "1")
    monkeypatch.setattr(drive, "WRITERS", 1)
    one = tmp_path / "one"
    one.mkdir()
    assert _mesh(short_drive, one / "t.glb", *argv) == 0
    said_one = capsys.readouterr().out
    monkeypatch.setattr(drive, "WRITERS", 2)
    real_write, real_build = files.write, texture.build_atlas
    second_build, builds = threading.Event(), []

    def write(path: Path, *args: object, **kwargs: object) -> int:
        if path.name.endswith("_000.glb"):
            assert second_build.wait(timeout=20), "the second tile waited for the first"
        return real_write(path, *args, **kwargs)  # type: ignore[arg-type]

    def build_atlas(*args: object) -> texture.Atlas:
        builds.append(1)
        if len(builds) == 2:
            second_build.set()
        return real_build(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(files, "write", write)
    monkeypatch.setattr(texture, "build_atlas", build_atlas)
    two = tmp_path / "two"
    two.mkdir()
    assert _mesh(short_drive, two / "t.glb", *argv) == 0
    said_two = capsys.readouterr().out
    made = sorted(p.name for p in two.glob("t_*.glb"))
    assert len(made) >= 3 and made == sorted(p.name for p in one.glob("t_*.glb"))
    assert all((one / m).read_bytes() == (two / m).read_bytes() for m in made)
    counts = [line for line in said_one.splitlines() if "facets" in line]
    assert counts and counts == [line for line in said_two.splitlines() if "facets" in line]


def test_a_full_disk_at_a_tile_is_one_line_exit_3(
    short_drive: Drive, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    from acq.mesh import files

    real, calls = files.write, []

    def write(path: Path, *args: object, **kwargs: object) -> int:
        calls.append(path)
        if len(calls) == 2:  # the disk (which cannot fill here) full at the second tile
            raise OSError(28, "No space left on device", str(path))
        return real(path, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(files, "write", write)
    assert _mesh(short_drive, tmp_path / "t.glb", "--tile-m", "3") == 3
    err = capsys.readouterr().err
    assert err.startswith(f"acq mesh: {tmp_path / 't_001.glb'}: no space left on the disk")
    assert err.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t_000.glb"]
