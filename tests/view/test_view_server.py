"""acq view's server over real HTTP on 127.0.0.1: the page, its files and vendored
libraries, the layer list, the layers' bytes, and nothing else."""

from __future__ import annotations

import hashlib
import http.client
import json
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from plyfile import PlyData

from acq.errors import InputError
from acq.view import ViewServer
from acq.view.static import VENDOR, import_map, module_imports, resolve_import
from tests.view.layer_files import cloud, mesh, unpack


def _get(url: str) -> tuple[int, str, bytes]:
    """Status, Content-Type and body of a GET."""
    try:
        with urllib.request.urlopen(url, timeout=10) as r:
            return r.status, r.headers["Content-Type"], r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.headers["Content-Type"], e.read()


def _raw_get(server: ViewServer, path: str, headers: dict[str, str] | None = None) -> int:
    """The status of a GET of ``path`` sent as it is (urllib would normalise ``..``)."""
    host, port = server.url.removeprefix("http://").rstrip("/").rsplit(":", 1)
    conn = http.client.HTTPConnection(host, int(port), timeout=10)
    try:
        conn.request("GET", path, headers=headers or {})
        response = conn.getresponse()
        response.read()
        return response.status
    finally:
        conn.close()


@pytest.fixture
def served(tmp_path: Path) -> tuple[ViewServer, list[Path]]:
    paths = [cloud(tmp_path / "cloud.ply"), mesh(tmp_path / "mesh.glb", offset=1000.0)]
    paths.append(mesh(tmp_path / "facets.ply"))
    with ViewServer(paths) as server:
        yield server, paths


def test_the_page_and_its_files_with_their_types(served: tuple[ViewServer, list[Path]]) -> None:
    server, _ = served
    assert server.url.startswith("http://127.0.0.1:") and server.url.endswith("/")
    status, kind, body = _get(server.url)
    assert status == 200 and kind.startswith("text/html")
    assert b'id="message"' in body and b'src="/static/viewer.js"' in body
    for name, expected in [
        ("viewer.js", "text/javascript"), ("viewer.css", "text/css"),
        ("vendor/three/build/three.module.js", "text/javascript"),
        ("vendor/VENDORED.json", "application/json"),
    ]:  # fmt: skip
        status, kind, body = _get(f"{server.url}static/{name}")
        assert status == 200 and kind.split(";")[0] == expected, name
        assert body == (VENDOR.parent / name).read_bytes()


def test_layers_listed_and_served_byte_for_byte(served: tuple[ViewServer, list[Path]]) -> None:
    server, paths = served
    status, kind, body = _get(f"{server.url}api/layers")
    assert status == 200 and kind == "application/json"
    layers = json.loads(body)
    assert [(x["name"], x["kind"], x["count"]) for x in layers] == [
        ("cloud.ply", "cloud", 500), ("mesh.glb", "mesh", 4), ("facets.ply", "mesh", 4),
    ]  # fmt: skip
    for layer, path in zip(layers, paths, strict=True):
        assert layer["bytes"] == path.stat().st_size
        status, kind, body = _get(server.url.rstrip("/") + layer["url"])
        if layer["kind"] == "mesh":
            assert status == 200 and body == path.read_bytes(), layer["url"]
    # a cloud comes as its points packed (acq.view.points_payload)
    assert layers[0]["url"] == "/data/0/points.bin"
    status, kind, body = _get(server.url.rstrip("/") + layers[0]["url"])
    assert status == 200 and kind == "application/octet-stream"
    vertex = PlyData.read(str(paths[0]))["vertex"]
    xyz = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1)
    assert np.abs(unpack(body)["xyz"] - xyz).max() < 1e-5
    # its other attributes apart, for the colour modes: those of the same points
    assert layers[0]["attributes"] == "/data/0/attributes.bin"
    assert "attributes" not in layers[1] and "attributes" not in layers[2]
    status, kind, more = _get(server.url.rstrip("/") + layers[0]["attributes"])
    assert status == 200 and kind == "application/octet-stream"
    got = unpack(body, more)
    assert (got["scan"] == vertex["scalar_scan"]).all() and (
        got["scan"] == np.arange(500) // 50
    ).all()
    assert _get(server.url.rstrip("/") + layers[1]["url"])[1] == "model/gltf-binary"


def test_nothing_else_is_served(served: tuple[ViewServer, list[Path]], tmp_path: Path) -> None:
    server, _ = served
    (tmp_path / "secret.txt").write_text("not for the page")
    for path in [
        "/nothing", "/static/", "/static/nothing.js", "/static/../view/server.py",
        "/static/%2e%2e/server.py", "/static/vendor/../../server.py", "/data/0/other.ply",
        "/data/3/cloud.ply", "/data/x/cloud.ply", "/data/../secret.txt",
        "/data/0/../../secret.txt", "/data/0/%2e%2e%2fsecret.txt", "/data/0/cloud.ply/x",
        "/data/1/attributes.bin", "/data/0/attributes.bin/x", "/data/0/cloud-attributes.bin",
        "//etc/passwd", "/static//etc/passwd",
    ]:  # fmt: skip
        assert _raw_get(server, path) == 404, path


def test_only_loopback_names_are_answered_on_loopback(
    served: tuple[ViewServer, list[Path]],
) -> None:
    server, _ = served
    port = server.url.rstrip("/").rsplit(":", 1)[1]
    for host in (f"127.0.0.1:{port}", f"localhost:{port}", f"[::1]:{port}", "127.0.0.1"):
        assert _raw_get(server, "/api/layers", {"Host": host}) == 200, host
    # a page of another site whose name was made to resolve to 127.0.0.1 (DNS rebinding)
    for host in (f"attacker.example:{port}", "192.168.1.20", "[::1", ""):
        assert _raw_get(server, "/data/0/cloud.ply", {"Host": host}) == 403, host


def test_vendored_files_match_their_record_and_every_import_is_served(
    served: tuple[ViewServer, list[Path]],
) -> None:
    server, _ = served
    record = json.loads((VENDOR / "VENDORED.json").read_text())
    assert record["package"] == "three" and record["version"].startswith("0.187.")
    assert record["integrity"].startswith("sha512-")
    listed = {f["path"] for f in record["files"]}
    on_disk = {str(p.relative_to(VENDOR)) for p in VENDOR.rglob("*") if p.is_file()}
    assert on_disk - {"VENDORED.json"} == listed
    for f in record["files"]:
        assert hashlib.sha256((VENDOR / f["path"]).read_bytes()).hexdigest() == f["sha256"]
    imports = import_map(_get(server.url)[2].decode())
    assert set(imports) == {"three", "three/addons/"}
    # every module the page loads, from viewer.js on, fetched as the browser would
    todo, seen = [f"{server.url}static/viewer.js"], set()
    while todo:
        url = todo.pop()
        if url in seen:
            continue
        seen.add(url)
        status, kind, body = _get(url)
        assert status == 200 and kind.startswith("text/javascript"), url
        for spec in module_imports(body.decode()):
            resolved = resolve_import(spec, url, imports)
            assert resolved is not None, f"{url}: {spec}"
            todo.append(resolved)
    names = {u.rsplit("/", 1)[1] for u in seen}
    assert {"three.module.js", "three.core.js", "GLTFLoader.js", "PLYLoader.js"} <= names
    assert {"OrbitControls.js", "BufferGeometryUtils.js", "SkeletonUtils.js"} <= names


def test_module_imports_reads_statements_not_comments() -> None:
    source = (
        "import * as THREE from 'three';\nimport {\n\tA,\n\tB\n} from \"./b.js\";\n"
        "export { C } from '../c.js';\nimport './side.js';\n"
        " * @three_import import { X } from 'three/addons/x.js';\n"
        "export function f() { return 'x'; }\nconst s = 'import y from \"z\"';\n"
    )
    assert module_imports(source) == ["three", "./b.js", "../c.js", "./side.js"]
    imports = {"three": "/static/t.js", "three/addons/": "/static/jsm/"}
    base = "http://h:1/static/jsm/loaders/L.js"
    assert resolve_import("three", base, imports) == "http://h:1/static/t.js"
    assert resolve_import("three/addons/x/y.js", base, imports) == "http://h:1/static/jsm/x/y.js"
    assert resolve_import("../u/v.js", base, imports) == "http://h:1/static/jsm/u/v.js"
    assert resolve_import("lodash", base, imports) is None


def test_a_folder_stands_for_its_viewable_files(tmp_path: Path) -> None:
    cloud(tmp_path / "b.ply")
    mesh(tmp_path / "a.glb")
    (tmp_path / "notes.txt").write_text("not a layer")
    with ViewServer([tmp_path]) as server:
        assert [x["name"] for x in server.listing()] == ["a.glb", "b.ply"]
        assert [x["url"] for x in server.listing()] == ["/data/0/a.glb", "/data/1/points.bin"]


def test_a_name_that_needs_quoting_is_served(tmp_path: Path) -> None:
    path = mesh(tmp_path / "tile 7#b?é.ply")
    with ViewServer([path]) as server:
        (layer,) = server.listing()
        assert layer["url"] == "/data/0/tile%207%23b%3F%C3%A9.ply"
        assert _get(server.url.rstrip("/") + layer["url"])[2] == path.read_bytes()


def _refusal(tmp_path: Path, name: str, data: bytes) -> str:
    path = tmp_path / name
    path.write_bytes(data)
    with pytest.raises(InputError) as e:
        ViewServer([path])
    assert str(path) in str(e.value) and "\n" not in str(e.value)
    return str(e.value)


def test_malformed_files_are_refused_naming_them(tmp_path: Path) -> None:
    good_cloud = cloud(tmp_path / "good.ply").read_bytes()
    good_glb = mesh(tmp_path / "good.glb").read_bytes()
    assert "PLY" in _refusal(tmp_path, "short.ply", good_cloud[:-7])
    assert "PLY" in _refusal(tmp_path, "garbage.ply", b"\x00\xffnot a ply at all" * 10)
    assert "PLY" in _refusal(tmp_path, "empty.ply", b"")
    header = good_cloud.split(b"end_header\n")[0]
    assert "no vertex" in _refusal(tmp_path, "none.ply", header.replace(b" 500\n", b" 0\n")
                                   + b"end_header\n")  # fmt: skip
    assert "bytes" in _refusal(tmp_path, "short.glb", good_glb[:-5])
    assert "glTF header" in _refusal(tmp_path, "garbage.glb", b"PK\x03\x04" + b"\x00" * 60)
    # a JSON chunk that is no JSON, its lengths kept right
    n = int.from_bytes(good_glb[12:16], "little")
    assert "JSON" in _refusal(tmp_path, "json.glb", good_glb[:20] + b"{" * n + good_glb[20 + n :])
    assert "not a file acq view shows" in _refusal(tmp_path, "cloud.xyz", b"0 0 0")


def test_non_finite_points_are_refused(tmp_path: Path) -> None:
    path = cloud(tmp_path / "nan.ply", n=20)
    data = bytearray(path.read_bytes())
    start = data.index(b"end_header\n") + len(b"end_header\n")
    row = len(data[start:]) // 20
    data[start + 3 * row : start + 3 * row + 8] = b"\x00" * 6 + b"\xf8\x7f"  # x of point 3: NaN
    path.write_bytes(data)
    with pytest.raises(InputError, match=r"nan\.ply: 1 vertices with a non-finite.*vertex 3"):
        ViewServer([path])


def test_missing_and_empty_folders_are_refused(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"gone\.ply: No such file"):
        ViewServer([tmp_path / "gone.ply"])
    (tmp_path / "d").mkdir()
    with pytest.raises(
        InputError, match=r"d: a folder with no \.ply, \.glb, \.las, \.laz or \.mcap file"
    ):
        ViewServer([tmp_path / "d"])
