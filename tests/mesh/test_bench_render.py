"""bench/mesh_render.py end to end on a 2 s two-camera drive, with the textured mesh: its
JSON line and picture."""

from __future__ import annotations

import contextlib
import io
import json
import sys
from pathlib import Path

import cv2
import pytest

from tests.bench_scripts import load

bench = load("mesh_render")


def test_the_mesh_the_textured_mesh_and_the_cloud_are_judged_from_three_views(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    png = tmp_path / "views.png"
    argv = ["mesh_render.py", "--seconds", "2", "--work", str(tmp_path), "--picture", str(png),
            "--texture"]  # fmt: skip
    monkeypatch.setattr(sys, "argv", argv)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        bench.main()
    row = json.loads(out.getvalue())
    assert list(row["views"]) == ["left", "right", "oblique"]
    assert row["facets"] > 0 and row["points"] >= row["vertices"] > 0
    assert row["textured_facets"] == row["facets"] and row["texels"] == 8
    assert row["glb_bytes"]["textured"] > row["glb_bytes"]["mesh"] > 0
    for kind in ("mesh", "textured", "cloud"):
        fig = row[kind]
        assert fig["street_px"] == sum(v[kind]["street_px"] for v in row["views"].values())
        # the laser saw the facades beside the drive: they come out close to the truth
        # (2 s: covered 0.58-0.63, within_24 0.78-0.88, 17-21 dB)
        assert fig["covered"] > 0.4 and fig["within_24"] > 0.6 and fig["psnr_db"] > 14
    img = cv2.imread(str(png))
    assert img is not None and img.shape[1] == 4 * 320  # truth, mesh, textured, cloud
    # the same facets: the textured mesh covers what the vertex-coloured one does
    assert row["textured"]["covered"] == row["mesh"]["covered"]
