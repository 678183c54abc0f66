"""LAS, LAZ and COPC clouds served by acq view over real HTTP on 127.0.0.1: their points
packed for the page (acq.view.points_payload) decode back to the file's, a cloud over the
limit is an evenly spread subset, and a bad file is refused naming it."""

from __future__ import annotations

import struct
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from acq.errors import InputError
from acq.view import ViewServer
from tests.view.layer_files import las_cloud, unpack

FAR = (431_000.0, 4_582_000.0, 12.0)  # a projected CRS's coordinates (m)


def _decode(data: bytes) -> tuple[int, int, np.ndarray, np.ndarray, np.ndarray, int]:
    """A payload's served count, file count, origin, xyz (float64, origin added), rgb
    (zeros without colours) and flags."""
    got = unpack(data)
    m = got["shown"]
    rgb = got.get("rgb", np.zeros((m, 3), np.uint8))
    return m, got["rows"], np.array(got["origin"]), got["xyz"], rgb, got["flags"]


def _points(server: ViewServer, k: int = 0) -> bytes:
    url = server.url.rstrip("/") + server.listing()[k]["url"]
    with urllib.request.urlopen(url, timeout=30) as r:
        assert r.headers["Content-Type"] == "application/octet-stream"
        return r.read()


@pytest.mark.parametrize("name", ["c.las", "c.laz", "c.copc.laz"])
def test_points_decode_back_to_the_files(tmp_path: Path, name: str) -> None:
    path, xyz, rgb = las_cloud(tmp_path / name, n=3000, at=FAR)
    with ViewServer([path]) as server:
        (layer,) = server.listing()
        data = _points(server)
    assert layer["kind"] == "cloud" and layer["count"] == layer["shown"] == 3000
    assert layer["url"] == "/data/0/points.bin" and layer["name"] == name
    m, count, origin, got, colours, flags = _decode(data)
    assert m == count == 3000 and flags == 63  # every column acq writes
    # COPC reorders the points by its octree: compared sorted alike, by their mm
    order, want = (np.lexsort(np.rint(a * 1000).T) for a in (got, xyz))
    # the file holds mm (its scale); float32 offsets within 10 m of the origin: < 1 µm more
    assert np.abs(got[order] - xyz[want]).max() < 0.0006
    assert (colours[order] == rgb[want]).all()
    assert np.abs(got - origin).max() < 20


def test_a_cloud_over_the_limit_is_an_evenly_spread_subset(tmp_path: Path) -> None:
    path, xyz, _ = las_cloud(tmp_path / "c.laz", n=10_000)
    with ViewServer([path], max_points=3000) as server:
        (layer,) = server.listing()
        m, count, _, got, _, _ = _decode(_points(server))
    assert (layer["count"], layer["shown"]) == (10_000, 3000) and (m, count) == (3000, 10_000)
    index = np.arange(3000) * 10_000 // 3000
    assert np.abs(got - xyz[index]).max() < 0.0006
    with ViewServer([path], max_points=10_000) as server:
        assert server.listing()[0]["shown"] == 10_000
    with pytest.raises(ValueError, match="max_points 0"):
        ViewServer([path], max_points=0)


def test_a_cloud_of_several_chunks_keeps_its_order(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr("acq.view.las_rows._CHUNK_POINTS", 777)  # many chunks, small file
    path, xyz, _ = las_cloud(tmp_path / "c.las", n=5000)
    with ViewServer([path], max_points=1234) as server:
        _, _, _, got, _, _ = _decode(_points(server))
    assert np.abs(got - xyz[np.arange(1234) * 5000 // 1234]).max() < 0.0006


def test_a_colourless_cloud_says_so(tmp_path: Path) -> None:
    import laspy

    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.01, 0.01, 0.01])
    las = laspy.LasData(header)
    las.x, las.y, las.z = np.arange(10.0), np.zeros(10), np.ones(10)
    las.write(tmp_path / "grey.las")
    with ViewServer([tmp_path / "grey.las"]) as server:
        m, _, _, got, rgb, flags = _decode(_points(server))
    assert m == 10 and flags == 2 | 8 and (rgb == 0).all()  # format 6: time, intensity
    assert np.allclose(got[:, 0], np.arange(10.0))


def test_bad_las_headers_are_refused_naming_them(tmp_path: Path) -> None:
    las, _, _ = las_cloud(tmp_path / "good.las", n=2000)
    garbage = tmp_path / "garbage.laz"
    garbage.write_bytes(b"not a las file at all" * 20)
    cut_las = tmp_path / "cut.las"
    cut_las.write_bytes(las.read_bytes()[:-100])
    empty = tmp_path / "empty.las"
    empty.write_bytes(b"")
    for bad, says in [
        (garbage, "not a readable LAS/LAZ file"),
        (cut_las, "truncated"),
        (empty, "empty.las"),
    ]:
        with pytest.raises(InputError) as e:
            ViewServer([las, bad])
        assert str(e.value).startswith(f"{bad}: ") and says in str(e.value), str(e.value)
        assert "\n" not in str(e.value)


def test_points_found_bad_while_decoding_are_said_on_their_url_and_to_the_caller(
    tmp_path: Path,
) -> None:
    import urllib.error

    las, _, _ = las_cloud(tmp_path / "good.las", n=2000)
    laz, _, _ = las_cloud(tmp_path / "good.laz", n=20_000)
    cut_laz = tmp_path / "cut.laz"  # its header whole, its points cut
    cut_laz.write_bytes(laz.read_bytes()[: laz.stat().st_size // 2])
    huge = tmp_path / "huge.las"  # its x scale 1e35 (at byte 131 of a LAS header)
    huge.write_bytes(las.read_bytes()[:131] + struct.pack("<d", 1e35) + las.read_bytes()[139:])
    said: list[str] = []
    with ViewServer([huge, las, cut_laz], on_error=said.append) as server:
        assert server.wait(60)
        for k, (bad, says) in enumerate([(huge, "too far apart for 32-bit floats"), (cut_laz, "")]):
            url = server.url.rstrip("/") + server.listing()[2 * k]["url"]
            with pytest.raises(urllib.error.HTTPError) as e:
                urllib.request.urlopen(url, timeout=30)
            assert e.value.code == 422
            text = e.value.read().decode()
            e.value.close()
            assert text.startswith(f"{bad}: ") and says in text and "\n" not in text, text
            assert text in said
        assert unpack(_points(server, 1))["shown"] == 2000  # the good one among them
    assert len(said) == 2


def test_a_las_layers_url_is_its_points_only(tmp_path: Path) -> None:
    import urllib.error

    path, _, _ = las_cloud(tmp_path / "c.las", n=100)
    with ViewServer([path]) as server:
        for wrong in ("/data/0/c.las", "/data/1/points.bin", "/data/0/points.bin/x"):
            with pytest.raises(urllib.error.HTTPError) as e:
                urllib.request.urlopen(server.url.rstrip("/") + wrong, timeout=10)
            assert e.value.code == 404
            e.value.close()
