"""What bench/mesh_reprojection.py measures: each facet corner's pixel in its facet's
view against the truth's, on facets made by hand over a real simulated drive (known
errors), and through `acq mesh --texture`'s own views (MeshJob.on_views) on the short
drive with the true calibration."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from acq.cloud.chunks import NO_CAMERA
from acq.mesh.drive import TileViews, prepare_mesh
from acq.sim.drive_log import DriveTruth
from tests.bench_scripts import load

bench = load("mesh_reprojection")
colorize_cameras = load("colorize_cameras")


def test_corner_errors_are_the_pixels_distances_from_the_truth(
    short_drive: tuple[DriveTruth, Path],
) -> None:
    truth = short_drive[0]
    name = truth.camera_names[0]
    cam = truth.cameras[name]
    k = cam.frame_t_s.size // 2
    # four vertices the camera sees (so each has a true pixel in frame k) and one no hit
    scan, step = np.nonzero(truth.visible[..., 0])
    pick = np.flatnonzero(np.abs(truth.point_t_s()[scan, step] - cam.frame_t_s[k]) < 0.01)[:4]
    miss = np.argwhere(~np.isfinite(truth.points).all(axis=2))[0]
    scan = np.r_[scan[pick], miss[0]]
    step = np.r_[step[pick], miss[1]]
    stamps = np.full(5, cam.frame_stamp_ns[k])
    uv, ok = truth.true_pixels(scan, step, stamps, camera=name)
    assert ok.tolist() == [True] * 4 + [False]
    offsets = np.array([[0.24, 0.32], [0.0, -0.9], [2.0, 0.0], [0.0, 0.0], [0.0, 0.0]])
    px = (uv + offsets).astype(np.float32)
    views = TileViews(
        scan=scan, step=step,
        # vertex 0 coloured from frame k (the colouring's pixel), 1 from the next frame,
        # 2 from none (both projected into frame k); 4 has no hit
        camera=np.array([0, 0, NO_CAMERA, 0, 0], np.uint8),
        frame=np.array([k, k + 1, -1, k, k]),
        faces=np.array([[0, 1, 2], [3, 4, 0], [0, 1, 3]]),
        view_cam=np.array([0, 0, -1]),  # the last facet has no view: none of its corners
        view_frame=np.array([k, k, -1]),
        corner_px=np.stack([px[[0, 1, 2]], px[[3, 4, 0]], px[[0, 1, 3]]]),
    )  # fmt: skip
    views.corner_px[1, 0] = np.nan  # vertex 3 off the sensor in facet 1
    got = bench.corner_errors(truth, views, [cam.frame_stamp_ns], [name])
    # facet 0's three corners, facet 1's vertex 0 (vertex 3: no pixel, vertex 4: no hit)
    want = [0.4, 0.9, 2.0, 0.4]
    assert np.allclose(got.error, want, atol=1e-3)
    assert got.own.tolist() == [True, False, False, True]
    assert got.camera.tolist() == [0, 0, 0, 0]
    t = truth.point_t_s()[scan[[0, 1, 2, 0]], step[[0, 1, 2, 0]]]
    assert np.allclose(got.gap_s, cam.frame_t_s[k] - t)
    fig = bench.figures(got.error)
    assert fig["corners"] == 4 and fig["within_0_5px"] == 0.5 and fig["within_1px"] == 0.75
    for key, value in (("mean_px", np.mean(want)), ("std_px", np.std(want)),
                       ("median_px", 0.65), ("p95_px", np.percentile(want, 95))):  # fmt: skip
        assert fig[key] == pytest.approx(value, abs=1e-3), key
    split = bench.summary(got, [name])
    assert split["own"]["corners"] == 2 and split["own"]["mean_px"] == pytest.approx(0.4, abs=1e-3)
    assert split["projected"]["mean_px"] == pytest.approx(1.45, abs=1e-3)
    assert sum(b.get("corners", 0) for b in split["by_time_gap"].values()) == 4


def test_acq_meshs_own_views_with_the_true_calibration_land_on_the_true_pixels(
    short_drive: tuple[DriveTruth, Path], tmp_path: Path
) -> None:
    """The views `acq mesh --texture` samples from (given by MeshJob.on_views, a tile at
    a time) put every corner with a pixel within a few tenths of a pixel of its truth
    when the calibration and the time offset are the truth's (odometry: the log's)."""
    truth = short_drive[0]
    calib = colorize_cameras.true_calibration(truth)
    tiles: list[TileViews] = []
    mj = prepare_mesh(truth.files, calib, tmp_path / "t.glb", texels=8, tile_m=5.0)
    mj.on_views = tiles.append
    rep = mj.run()
    assert len(tiles) == len(rep.files) > 1
    assert sum(v.faces.shape[0] for v in tiles) == rep.facets
    textured = sum(
        int(((v.view_cam >= 0) & np.isfinite(v.corner_px).all(axis=(1, 2))).sum()) for v in tiles
    )
    assert textured == rep.textured
    stamps = [cj.frame_old for cj in mj.job.cameras]
    got = bench.Corners.join(
        [bench.corner_errors(truth, v, stamps, truth.camera_names) for v in tiles]
    )
    assert got.error.size > 0.9 * 3 * textured
    assert 0.01 < 1 - got.own.mean() < 0.9  # some corners projected into another frame
    for part in (got.own, ~got.own):
        e = got.error[part]
        assert np.median(e) < 0.3 and np.percentile(e, 95) < 1.0, np.percentile(e, [50, 95])
