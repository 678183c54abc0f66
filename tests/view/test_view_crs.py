"""The CRS of acq view's layers in ``/api/layers`` over real HTTP on 127.0.0.1: read from a
LAS/LAZ/COPC file as acq's LasStream writes it (WKT), as laspy writes GeoTIFF keys or a
compound CRS's WKT, from a PLY's ``comment crs``; none for acq's local frames and a .glb;
a malformed CRS leaves the file shown with a note; degrees or feet are refused."""

from __future__ import annotations

import json
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from acq.cloud.ply import PlyStream
from acq.view import ViewServer
from tests.view.layer_files import cloud, las_cloud, mesh
from tests.view.test_view_cli import _refused

FAR = (431_000.0, 4_582_000.0, 12.0)
UTM31 = {"name": "EPSG:25831", "epsg": 25831, "units": "metre", "projected": True, "note": None}


def _listed(server: ViewServer) -> list[dict[str, object]]:
    with urllib.request.urlopen(server.url + "api/layers", timeout=30) as r:
        listing: list[dict[str, object]] = json.load(r)
    return listing


def _laspy_file(path: Path, crs: str | None, version: str = "1.4", wkt: str | None = None) -> Path:
    """A LAS file of 10 points written by laspy itself: ``crs`` added the way laspy does
    (LAS 1.2: GeoTIFF keys; 1.4: a WKT VLR), or ``wkt`` as the WKT VLR's raw text."""
    import laspy
    import pyproj
    from laspy.vlrs.known import WktCoordinateSystemVlr

    header = laspy.LasHeader(version=version, point_format=3 if version == "1.2" else 7)
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array(FAR)
    if crs is not None:
        header.add_crs(pyproj.CRS.from_user_input(crs))
    if wkt is not None:
        header.vlrs.append(WktCoordinateSystemVlr(wkt))
        header.global_encoding.wkt = True
    las = laspy.LasData(header)
    rng = np.random.default_rng(0)
    las.x, las.y, las.z = (FAR[k] + rng.uniform(0, 10, 10) for k in range(3))
    las.write(path)
    return path


@pytest.mark.parametrize("name", ["c.las", "c.laz", "c.copc.laz"])
def test_the_crs_acq_writes_is_listed(tmp_path: Path, name: str) -> None:
    path, _, _ = las_cloud(tmp_path / name, n=200, at=FAR)  # crs="EPSG:25831", as --crs does
    with ViewServer([path]) as server:
        (layer,) = _listed(server)
    assert layer["crs"] == UTM31


def test_geotiff_keys_and_a_compound_crs_written_by_laspy_are_read(tmp_path: Path) -> None:
    geotiff = _laspy_file(tmp_path / "geotiff.las", "EPSG:32631", version="1.2")
    compound = _laspy_file(tmp_path / "compound.las", "EPSG:25831+5782")
    with ViewServer([geotiff, compound]) as server:
        first, second = _listed(server)
    assert first["crs"] == {**UTM31, "name": "EPSG:32631", "epsg": 32631}
    # a projected CRS with a height: no single EPSG code, named by its own name
    assert second["crs"] == {
        **UTM31, "name": "ETRS89 / UTM zone 31N + Alicante height", "epsg": None
    }  # fmt: skip


def _ply(path: Path, comments: list[str]) -> Path:
    """A PLY cloud of 10 points as `acq colorize` writes it, with ``comments``."""
    out = PlyStream(path, comments, ["left"])
    n = 10
    out.write(
        np.full((n, 3), FAR), np.zeros((n, 3), np.uint8), np.zeros(n), np.ones(n, np.float32),
        np.zeros(n, np.int32), np.ones(n, bool), np.zeros(n, np.uint8), np.zeros(n, np.int32),
    )  # fmt: skip
    out.close()
    return path


def test_a_ply_s_crs_comment_is_read_and_local_frames_have_none(tmp_path: Path) -> None:
    geo = _ply(tmp_path / "geo.ply", ["frame world", "view all", "crs EPSG:25831"])
    local = cloud(tmp_path / "local.ply")  # "frame world" alone: odometry or ENU, unsaid
    no_crs = _laspy_file(tmp_path / "none.las", None)
    with ViewServer([geo, local, no_crs, mesh(tmp_path / "m.glb")]) as server:
        crs = [layer["crs"] for layer in _listed(server)]
    assert crs == [UTM31, None, None, None]


def test_a_malformed_crs_leaves_the_file_shown_with_a_note(tmp_path: Path) -> None:
    bad = _laspy_file(tmp_path / "bad.las", None, wkt='PROJCS["broken"')
    with ViewServer([bad]) as server:
        (layer,) = _listed(server)
        with urllib.request.urlopen(server.url.rstrip("/") + str(layer["url"])) as r:
            assert r.status == 200 and len(r.read()) > 56  # its points are served
    crs = layer["crs"]
    assert isinstance(crs, dict) and crs["name"] is None and crs["projected"] is False
    assert str(crs["note"]).startswith("its CRS cannot be read (")
    assert str(crs["note"]).endswith("shown in the file's own coordinates")
    # a PLY's crs comment that names no CRS: the same
    with ViewServer([_ply(tmp_path / "bad.ply", ["frame world", "crs EPSG:0"])]) as server:
        (layer,) = _listed(server)
    assert layer["count"] == 10 and "EPSG:0" in str(layer["crs"]["note"])  # type: ignore[index]


def test_a_crs_not_in_metres_is_refused_naming_the_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    degrees = _laspy_file(tmp_path / "degrees.las", "EPSG:4326")
    line = _refused(capsys, [str(degrees)], "degrees.las", "geographic CRS (degrees)")
    assert "acq view draws metres" in line
    feet = _laspy_file(tmp_path / "feet.las", "EPSG:2263")  # NAD83 / New York Long Island (ftUS)
    _refused(capsys, [str(feet)], "feet.las", "US survey foot")
