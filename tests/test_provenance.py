"""acq's mark on the files it writes: images that decode as before, clouds and reports
that say they are acq's, and files of anyone else that do not."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from acq.cloud.las import LasStream
from acq.cloud.ply import PlyStream
from acq.provenance import SOFTWARE, made_by_acq, write_image

IMAGE = np.random.default_rng(0).integers(0, 255, (48, 64, 3), dtype=np.uint8)


@pytest.mark.parametrize("suffix", [".png", ".jpg", ".jpeg"])
def test_images_carry_the_mark_and_decode_as_without_it(suffix: str, tmp_path: Path) -> None:
    ours, theirs = tmp_path / f"a{suffix}", tmp_path / f"b{suffix}"
    write_image(ours, IMAGE)
    assert cv2.imwrite(str(theirs), IMAGE)
    assert made_by_acq(ours) and not made_by_acq(theirs)
    a, b = cv2.imread(str(ours)), cv2.imread(str(theirs))
    assert a is not None and b is not None and np.array_equal(a, b)
    assert [p.name for p in tmp_path.iterdir()].count(f"a{suffix}") == 1  # no temporary left


def test_an_image_that_cannot_be_written_names_its_path(tmp_path: Path) -> None:
    with pytest.raises(OSError, match="nowhere"):
        write_image(tmp_path / "nowhere" / "a.png", IMAGE)
    with pytest.raises(OSError, match="cannot encode"):
        write_image(tmp_path / "a.png", np.zeros((0, 0, 3), np.uint8))


def _points(n: int) -> tuple[np.ndarray, ...]:
    xyz = np.linspace(0, 1, 3 * n).reshape(n, 3)
    rgb = np.zeros((n, 3), np.uint8)
    ones = np.ones(n)
    columns = ones.astype(np.uint16), ones.astype(np.uint32), ones.astype(bool)
    return xyz, rgb, ones, *columns, ones.astype(np.uint8), ones.astype(np.int32)


@pytest.mark.parametrize(("stream", "name"), [(PlyStream, "c.ply"), (LasStream, "c.las")])
def test_clouds_carry_the_mark(stream: type, name: str, tmp_path: Path) -> None:
    path = tmp_path / name
    s = stream(path)
    s.write(*_points(5))
    s.close()
    assert made_by_acq(path)


def test_reports_and_other_files(tmp_path: Path) -> None:
    report, other = tmp_path / "r.json", tmp_path / "o.json"
    report.write_text(json.dumps({"software": SOFTWARE, "x": 1}, indent=2))
    other.write_text(json.dumps({"x": 1, "software": SOFTWARE}))
    assert made_by_acq(report) and not made_by_acq(other)
    for data in (b"", b"ply\nformat ascii 1.0\nend_header\ncomment acq x\n", b"LASF" + bytes(300),
                 b"\x89PNG\r\n\x1a\n" + bytes(64), b"acq 0.1.0"):  # fmt: skip
        other.write_bytes(data)
        assert not made_by_acq(other), data


def test_a_glb_is_acqs_by_its_asset_generator_wherever_the_json_puts_it(tmp_path: Path) -> None:
    import struct

    def glb(tree: dict[str, object]) -> bytes:
        text = json.dumps(tree, separators=(",", ":")).encode()
        text += b" " * (-len(text) % 4)
        return b"glTF" + struct.pack("<II", 2, 28 + len(text)) + struct.pack("<I", len(text)) \
            + b"JSON" + text + struct.pack("<I", 0) + b"BIN\0"  # fmt: skip

    path = tmp_path / "m.glb"
    extras_first = {"asset": {"extras": {"acq": ["a } b", "{"]}, "generator": SOFTWARE}}
    for tree, ours in [
        (extras_first, True),
        ({"accessors": [{"count": 1}], "asset": {"version": "2.0", "generator": "acq 9"}}, True),
        ({"asset": {"generator": "trimesh"}}, False),
        ({"asset": {"version": "2.0"}}, False),
        ({"asset": "acq 1"}, False),
        (["acq "], False),
    ]:
        path.write_bytes(glb(tree))  # type: ignore[arg-type]
        assert made_by_acq(path) is ours, tree
    whole = glb(extras_first)
    for data in (whole[:40], whole[:20] + b"not json" + whole[28:], whole[:12]):
        path.write_bytes(data)  # a JSON chunk cut short, or not JSON
        assert not made_by_acq(path)


def test_an_e57_carries_the_mark_in_its_xml_section(tmp_path: Path) -> None:
    from acq.cloud.e57 import E57Stream

    path = tmp_path / "c.e57"
    s = E57Stream(path)
    s.write(*_points(5))
    s.close()
    assert made_by_acq(path)
    data = path.read_bytes()
    path.write_bytes(data.replace(b"[acq ", b"[abc "))
    assert not made_by_acq(path)
