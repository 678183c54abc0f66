"""The level of detail of LAS, LAZ and COPC layers (acq.view.lod): the chunks a file is
cut into (a COPC file's octree nodes, else runs of rows) and their boxes, checked against
laspy; rows [start, stop) of a file packed for the page; the chunk routes over real HTTP
on 127.0.0.1."""

from __future__ import annotations

import itertools
import json
import struct
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from acq.errors import InputError
from acq.view import ViewServer, lod
from acq.view.points_payload import payload
from tests.view.layer_files import cloud, las_cloud, unpack


def _decode(data: bytes) -> tuple[int, int, np.ndarray, np.ndarray, np.ndarray, int]:
    """A payload's served count, the rows of the range it stands for, origin, xyz
    (float64, origin added), rgb (zeros without colours) and flags."""
    got = unpack(data)
    m = got["shown"]
    rgb = got.get("rgb", np.zeros((m, 3), np.uint8))
    return m, got["stop"] - got["start"], np.array(got["origin"]), got["xyz"], rgb, got["flags"]


def _rows(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Every row's x y z (m) and 16-bit r g b, in file order, as laspy reads them."""
    import laspy

    las = laspy.read(path)
    return np.stack([las.x, las.y, las.z], axis=1), np.stack([las.red, las.green, las.blue], 1)


def _drive(path: Path, n: int) -> Path:
    """A LAS or LAZ cloud of ``n`` points along x (0-100 m) in time order, as a drive's."""
    import laspy

    rng = np.random.default_rng(5)
    header = laspy.LasHeader(point_format=7, version="1.4")
    header.scales, header.offsets = np.array([0.001] * 3), np.array([431_000.0, 4_582_000.0, 0])
    las = laspy.LasData(header)
    las.x = 431_000 + np.sort(rng.uniform(0, 100, n))
    las.y, las.z = 4_582_000 + rng.uniform(-4, 4, n), rng.uniform(0, 4, n)
    las.red, las.green, las.blue = (rng.integers(0, 65536, n, dtype=np.uint16) for _ in "rgb")
    las.write(path)
    return path


@pytest.mark.parametrize("name", ["d.las", "d.laz"])
def test_runs_cut_the_rows_and_box_them_by_the_subset(tmp_path: Path, name: str) -> None:
    path = _drive(tmp_path / name, 50_000)
    xyz, _ = _rows(path)
    coarse = payload(path, 5000)
    found = lod.chunks(path, 50_000, coarse, rows=6000)
    assert [(c.start, c.stop, c.level) for c in found] == [
        (a, min(a + 6000, 50_000), 0) for a in range(0, 50_000, 6000)
    ]
    for c in found:
        lo, hi = xyz[c.start : c.stop].min(axis=0), xyz[c.start : c.stop].max(axis=0)
        # inside the rows' true box (float32 offsets: < 0.1 mm out), short of it by no more
        # than the subset's spacing (a point in 10 along 12 m a run: ~0.2 m in x)
        assert (np.array(c.lo) >= lo - 1e-4).all() and (np.array(c.hi) <= hi + 1e-4).all()
        assert np.abs(np.array(c.lo) - lo).max() < 0.5 and np.abs(np.array(c.hi) - hi).max() < 0.5


def test_a_sparse_subset_makes_longer_runs(tmp_path: Path) -> None:
    path = _drive(tmp_path / "d.laz", 20_000)
    found = lod.chunks(path, 20_000, payload(path, 100), rows=1000)
    # 64 subset points a run at least: 64 * 20,000 / 100 rows
    assert [c.count for c in found] == [12_800, 7200]


def test_copc_chunks_are_its_octree_nodes(tmp_path: Path) -> None:
    import laspy

    path, _, _ = las_cloud(tmp_path / "c.copc.laz", n=120_000, at=(431_000.0, 4_582_000.0, 12.0))
    xyz, _ = _rows(path)
    found = lod.copc_chunks(path)
    assert found is not None and len(found) > 1
    assert found[0].start == 0 and found[-1].stop == 120_000
    assert all(a.stop == b.start for a, b in itertools.pairwise(found))
    assert [c.level for c in found if c.level == 0] == [0]  # one root
    for c in found:
        rows = xyz[c.start : c.stop]
        assert (rows >= np.array(c.lo) - 1e-9).all() and (rows <= np.array(c.hi) + 1e-9).all()
    # each level's rows are the points laspy's COPC reader gives for that level's nodes
    with laspy.CopcReader.open(path) as reader:
        for level in sorted({c.level for c in found}):
            got = reader.query(level=level)
            want = np.concatenate([xyz[c.start : c.stop] for c in found if c.level == level])
            mine = np.stack([got.x, got.y, got.z], axis=1)
            assert len(mine) == len(want)
            order = (np.lexsort(np.rint(a * 1000).T) for a in (mine, want))
            a, b = next(order), next(order)
            assert np.abs(mine[a] - want[b]).max() < 1e-6


def test_a_las_file_is_not_copc_and_a_lying_copc_file_is_refused(tmp_path: Path) -> None:
    las, _, _ = las_cloud(tmp_path / "c.las", n=100)
    assert lod.copc_chunks(las) is None
    path, _, _ = las_cloud(tmp_path / "c.copc.laz", n=1000)
    data = bytearray(path.read_bytes())
    # a LAS 1.4 header's point count (uint64 at byte 247), one more than the nodes hold
    struct.pack_into("<Q", data, 247, 1001)
    lying = tmp_path / "lying.copc.laz"
    lying.write_bytes(bytes(data))
    with pytest.raises(InputError) as e:
        lod.copc_chunks(lying)
    assert str(e.value) == (
        f"{lying}: its COPC hierarchy's nodes hold 1000 points, its header says 1001"
    )
    # the COPC info VLR's record (after the 375-byte header and a 54-byte VLR header):
    # the octree's centre x y z, then its half size, doubles
    data = bytearray(path.read_bytes())
    struct.pack_into("<d", data, 375 + 54 + 24, float("nan"))
    lying.write_bytes(bytes(data))
    with pytest.raises(InputError) as e:
        lod.copc_chunks(lying)
    assert str(e.value) == f"{lying}: its COPC octree's centre or half size is no number"
    # a hierarchy page that names itself as a node's page: refused, not read forever
    import laspy

    with laspy.CopcReader.open(path) as reader:
        at, size = reader.copc_info.hierarchy_root_offset, reader.copc_info.hierarchy_root_size
    data = bytearray(path.read_bytes())
    # the root page's first entry (the root node's): its key's 16 bytes, then its offset,
    # byte size and point count, -1 for a page
    struct.pack_into("<Qii", data, at + 16, at, size, -1)
    lying.write_bytes(bytes(data))
    with pytest.raises(InputError) as e:
        lod.copc_chunks(lying)
    assert (
        str(e.value) == f"{lying}: its COPC hierarchy's nodes hold 0 points, its header says 1000"
    )


@pytest.mark.parametrize("name", ["c.las", "c.laz", "c.copc.laz"])
def test_a_range_of_rows_is_packed_as_the_file_holds_them(tmp_path: Path, name: str) -> None:
    path, _, _ = las_cloud(tmp_path / name, n=3000, at=(431_000.0, 4_582_000.0, 12.0))
    xyz, rgb16 = _rows(path)
    m, count, _, got, rgb, _ = _decode(payload(path, 10_000, 1234, 2345))
    assert m == count == 1111
    assert np.abs(got - xyz[1234:2345]).max() < 0.0006
    assert (rgb == rgb16[1234:2345] // 257).all()  # acq writes c * 257
    # capped: evenly spread within the range
    m, count, _, got, _, _ = _decode(payload(path, 100, 1000, 3000))
    assert (m, count) == (100, 2000)
    assert np.abs(got - xyz[1000 + np.arange(100) * 2000 // 100]).max() < 0.0006
    for start, stop in ((0, 3001), (-1, 10), (5, 5)):
        with pytest.raises(ValueError, match=rf"rows \[{start}, {stop}\) of a file of 3000"):
            payload(path, 10, start, stop)


def _get(server: ViewServer, path: str) -> bytes:
    with urllib.request.urlopen(server.url.rstrip("/") + path, timeout=30) as r:
        data: bytes = r.read()
        return data


@pytest.mark.parametrize("name", ["c.laz", "c.copc.laz"])
def test_chunks_over_http_are_the_rows_they_name(tmp_path: Path, name: str) -> None:
    path, _, _ = las_cloud(tmp_path / name, n=120_000, at=(431_000.0, 4_582_000.0, 12.0))
    small = cloud(tmp_path / "small.ply")
    xyz, rgb16 = _rows(path)
    with ViewServer([path, small], max_points=10_000, run_points=30_000) as server:
        big, ply = server.listing()
        assert big["lod"] == "/data/0/lod.json" and "lod" not in ply
        chunks = json.loads(_get(server, big["lod"]))["chunks"]
        assert chunks == lod.index(server.chunks[0])["chunks"]
        assert chunks[0]["start"] == 0 and chunks[-1]["stop"] == 120_000
        for c in range(len(chunks)):
            m, count, _, got, rgb, _ = _decode(_get(server, f"/data/0/chunk/{c}.bin"))
            rows = slice(chunks[c]["start"], chunks[c]["stop"])
            assert m == count == chunks[c]["count"] == rows.stop - rows.start
            assert np.abs(got - xyz[rows]).max() < 0.0006 and (rgb == rgb16[rows] // 257).all()
        for wrong in (
            f"/data/0/chunk/{len(chunks)}.bin", "/data/0/chunk/-1.bin", "/data/0/chunk/x.bin",
            "/data/0/chunk/0", "/data/0/chunk/0.bin/x", "/data/0/chunks/0.bin",
            "/data/1/lod.json", "/data/1/chunk/0.bin", "/data/2/lod.json",
        ):  # fmt: skip
            with pytest.raises(urllib.error.HTTPError) as e:
                _get(server, wrong)
            assert e.value.code == 404, wrong
            e.value.close()


def test_a_cloud_within_the_limit_has_no_chunks(tmp_path: Path) -> None:
    path, _, _ = las_cloud(tmp_path / "c.laz", n=1000)
    with ViewServer([path], max_points=1000) as server:
        assert "lod" not in server.listing()[0] and server.chunks == {}


def test_a_file_cut_after_the_start_answers_its_chunk_with_an_error(tmp_path: Path) -> None:
    path = _drive(tmp_path / "d.las", 20_000)
    with ViewServer([path], max_points=1000, run_points=5000) as server:
        assert server.wait(60)  # the subset packed from the whole file
        path.write_bytes(path.read_bytes()[: -15 * 36])  # its last 15 points (36 bytes each) gone
        assert unpack(_get(server, "/data/0/chunk/0.bin"))["shown"] == 5000
        with pytest.raises(urllib.error.HTTPError) as e:
            _get(server, "/data/0/chunk/3.bin")
        text = e.value.read().decode()
        e.value.close()
    assert e.value.code == 500
    assert f"{path}: truncated: its header says 20000 points, they end at row 19985" in text
