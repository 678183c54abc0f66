"""Camera–laser extrinsic calibration (acq.calib.extrinsic, paper §3.2) on simulated boards."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from acq.calib import extrinsic as ex
from acq.calib.board_pose import BoardPose, board_pose_from_corners
from acq.calib.extrinsic_linear import linear_solution
from acq.calib.plots import residual_plot
from acq.cli.calibrate_extrinsic import _extrinsic_lines
from acq.geometry.rotations import rotation_angle, rotation_from_euler, rotvec_from_matrix
from acq.geometry.transforms import Rigid
from acq.sim.board_poses import Checkerboard, simulate
from acq.sim.world import default_lens


def _errors(estimate: Rigid, truth: Rigid) -> tuple[float, float]:
    """(rotation error rad, translation error m)."""
    dR = estimate.rotation @ truth.rotation.T
    return rotation_angle(dR), float(np.linalg.norm(estimate.translation - truth.translation))


def _error_vector(estimate: Rigid, truth: Rigid) -> np.ndarray:
    """The 6 parameters of the error as in ExtrinsicResult.std: left rotation vector, t."""
    dR = estimate.rotation @ truth.rotation.T
    return np.r_[rotvec_from_matrix(dR), estimate.translation - truth.translation]


def _synthetic(truth: Rigid, normals: np.ndarray, distances: np.ndarray) -> list[BoardPose]:
    """Exact poses built from P_laser = R @ P_camera + t: camera planes n . X = d, laser
    points on their intersection with the scan plane z = 0 (40 points over 0.8 m)."""
    R, t = truth.rotation, truth.translation
    poses = []
    for n, d in zip(normals, distances, strict=True):
        n = n / np.linalg.norm(n)
        m = R @ n  # the plane in the laser frame: m . P = d + m . t
        c = d + m @ t
        mxy = m[:2]
        p0 = mxy * c / (mxy @ mxy)
        along = np.array([-mxy[1], mxy[0]]) / np.linalg.norm(mxy)
        s = np.linspace(-0.4, 0.4, 40)[:, None]
        P = np.column_stack([p0 + s * along, np.zeros(len(s))])
        poses.append(BoardPose(n, d, P))
    return poses


def test_noiseless_data_are_recovered_exactly() -> None:
    data = simulate(12, seed=3, pixel_noise=0.0, range_noise=0.0)
    rot, trans = _errors(linear_solution(data.poses), data.truth)
    assert rot < 1e-9 and trans < 1e-9
    result = ex.calibrate(data.poses)
    rot, trans = _errors(result.camera_to_laser, data.truth)
    assert rot < 1e-9 and trans < 1e-9
    assert result.outliers == ()
    assert result.rms_m < 1e-9
    assert result.plane_errors  # the planes came with their covariance
    assert result.converged


def test_linear_solution_is_close_with_noise_and_refinement_improves_it() -> None:
    lin_total = ref_total = 0.0
    for seed in range(3):
        data = simulate(20, seed=seed)
        lin = linear_solution(data.poses)
        rot, trans = _errors(lin, data.truth)
        assert math.degrees(rot) < 3.0 and trans < 0.06
        result = ex.calibrate(data.poses)
        rot_r, trans_r = _errors(result.camera_to_laser, data.truth)
        assert math.degrees(rot_r) < 0.5 and trans_r < 0.012
        lin_total += math.degrees(rot) + trans * 100  # degrees + cm
        ref_total += math.degrees(rot_r) + trans_r * 100
        assert result.initial is not None
        assert _errors(result.initial, lin) == (0.0, 0.0)
    assert ref_total < 0.5 * lin_total


def test_covariance_matches_the_spread_over_seeds() -> None:
    errors, stds = [], []
    for seed in range(24):  # mean std / RMS error: 0.66-1.18 over other seed sets
        data = simulate(10, seed=100 + seed)
        result = ex.calibrate(data.poses)
        errors.append(_error_vector(result.camera_to_laser, data.truth))
        stds.append(result.std)
    rms_error = np.sqrt(np.mean(np.square(errors), axis=0))
    mean_std = np.mean(stds, axis=0)
    ratio = mean_std / rms_error
    assert np.all((ratio > 0.5) & (ratio < 2.0)), ratio
    np.testing.assert_allclose(stds[-1][3:] * 1e3, result.std_t_mm)
    np.testing.assert_allclose(np.degrees(stds[-1][:3]), result.std_rot_deg)


def test_the_plain_covariance_underestimates_when_planes_have_errors() -> None:
    # why refine() models the planes' errors: taken as exact, the formal std is far too small
    data = simulate(20, seed=7)
    full = ex.calibrate(data.poses)
    plain = ex.calibrate(data.poses, plane_errors=False)
    assert not plain.plane_errors and full.plane_errors
    assert plain.std_model is not None and plain.std_spread is not None
    assert np.all(plain.std_model < 0.6 * full.std)
    # the poses' spread sees the planes' errors the plain model leaves out
    assert np.all(plain.std_spread > 1.5 * plain.std_model)
    np.testing.assert_allclose(plain.std, np.maximum(plain.std_model, plain.std_spread))
    assert full.laser_noise_m is not None
    assert 0.007 < float(np.median(full.laser_noise_m)) < 0.013  # simulated: 10 mm


def _bowed(poses: list[BoardPose], rng: np.random.Generator, size_m: float) -> list[BoardPose]:
    """The poses with a range error common to each board's points (an offset and a
    slope along the board, ``size_m`` each): a real scanner's errors along one board
    are not independent."""
    out = []
    for p in poses:
        r = np.linalg.norm(p.points, axis=1, keepdims=True)
        s = np.linspace(-1.0, 1.0, len(r))[:, None]
        err = rng.normal(0.0, size_m) + rng.normal(0.0, size_m) * s
        out.append(replace(p, points=p.points * (1.0 + err / r)))
    return out


def test_the_reported_std_covers_errors_common_to_a_board() -> None:
    # each board's laser points share an error: the fit's model (independent points)
    # underestimates, the poses' spread does not
    errors, reported, model = [], [], []
    for seed in range(16):
        data = simulate(20, seed=200 + seed, true_planes=True, range_noise=0.002)
        poses = _bowed(data.poses, np.random.default_rng(seed), 0.006)
        result = ex.calibrate(poses)
        assert result.std_model is not None and result.std_spread is not None
        errors.append(_error_vector(result.camera_to_laser, data.truth))
        reported.append(result.std)
        model.append(result.std_model)
    rms_error = np.sqrt(np.mean(np.square(errors), axis=0))
    assert np.all(np.mean(model, axis=0) / rms_error < 0.5)
    ratio = np.mean(reported, axis=0) / rms_error
    assert np.all((ratio > 0.5) & (ratio < 2.0)), ratio
    d = result.to_dict()
    assert d["std_pose_spread"] == pytest.approx(list(result.std_spread))
    assert d["std_model"] == pytest.approx(list(result.std_model))
    # acq calibrate extrinsic says so beside the std it prints
    (line,) = [s for s in _extrinsic_lines(result, [], 0, "m") if s.startswith("  std")]
    ratio = float(np.max(result.std_spread / result.std_model))
    assert f"the poses' spread, up to {ratio:.1f}x the fit's model" in line


def test_few_poses_keep_the_model_std() -> None:
    data = simulate(6, seed=11)
    result = ex.calibrate(data.poses)
    assert result.std_spread is not None and np.isnan(result.std_spread).all()
    np.testing.assert_array_equal(result.std, result.std_model)
    assert result.to_dict()["std_pose_spread"] == [None] * 6
    assert not any("spread" in s for s in _extrinsic_lines(result, [], 0, "m"))


def test_an_outlier_pose_is_detected_and_dropped(tmp_path: Path) -> None:
    data = simulate(15, seed=5, n_outliers=1)
    (bad,) = data.outliers
    result = ex.calibrate(data.poses)
    assert bad in result.outliers
    assert len(result.outliers) <= 2
    assert result.residuals_per_pose.shape == (15,)
    assert result.residuals_per_pose[bad] > result.outlier_threshold_m
    rot, trans = _errors(result.camera_to_laser, data.truth)
    assert math.degrees(rot) < 0.5 and trans < 0.015
    kept = [p for i, p in enumerate(data.poses) if i not in result.outliers]
    assert rot < _errors(ex.calibrate(data.poses, max_rounds=0).camera_to_laser, data.truth)[0]
    assert len(kept) == 15 - len(result.outliers)

    path = tmp_path / "residuals.png"
    img = residual_plot(result, data.poses, path)
    assert path.stat().st_size > 0
    read = cv2.imread(str(path))
    assert read is not None and read.shape == img.shape
    red = (img[:, :, 2] > 200) & (img[:, :, 0] < 60)  # the dropped pose's bar
    assert red.sum() > 50


def test_fewer_than_five_poses_raise() -> None:
    data = simulate(4, seed=1, true_planes=True)
    with pytest.raises(ValueError, match="at least 5 board poses"):
        linear_solution(data.poses)
    with pytest.raises(ValueError, match="at least 5 board poses"):
        ex.calibrate(data.poses)


def test_degenerate_poses_raise() -> None:
    data = simulate(8, seed=2, parallel=True)
    with pytest.raises(ValueError, match="parallel"):
        ex.calibrate(data.poses)
    # normals all turned about one axis (camera y): translation along it undetermined
    truth = Rigid(rotation_from_euler(0.2, -0.1, 0.3), np.array([0.2, -0.1, 0.3]))
    angles = np.radians([-30, -15, 0, 10, 20, 35])
    normals = np.column_stack([np.sin(angles), np.zeros(6), -np.cos(angles)])
    poses = _synthetic(truth, normals, np.full(6, -2.0))
    with pytest.raises(ValueError, match="one plane"):
        linear_solution(poses)


def test_direction_convention_is_eq2_not_its_inverse() -> None:
    # P_laser = R @ P_camera + t: the returned transform is that one, not its inverse
    truth = Rigid(rotation_from_euler(0.4, -0.3, 1.1), np.array([0.35, -0.2, 0.15]))
    rng = np.random.default_rng(0)
    normals = rng.normal(size=(8, 3)) + np.array([0.0, 0.0, -3.0])
    poses = _synthetic(truth, normals, rng.uniform(-3.0, -1.0, 8))
    result = ex.calibrate(poses)
    np.testing.assert_allclose(result.camera_to_laser.rotation, truth.rotation, atol=1e-9)
    np.testing.assert_allclose(result.camera_to_laser.translation, truth.translation, atol=1e-9)
    assert _errors(result.camera_to_laser, truth.inverse())[1] > 0.1
    # and the residual is n . R^T (P - t) - d: zero for the truth
    for r in ex.point_residuals(poses, truth):
        assert np.abs(r).max() < 1e-12
    assert not result.plane_errors  # no plane covariances given


def test_board_pose_from_corners_past_90_degrees() -> None:
    lens = default_lens()
    obj = Checkerboard().corners()  # 9 x 7 corners over 0.8 x 0.6 m
    # board centre 82.7 degrees off the optical axis, 2.1 m away, facing the camera and
    # tilted so that its far corners lie up to 92 degrees off-axis, behind the lens plane
    theta = math.radians(82.7)
    centre = 2.1 * np.array([math.sin(theta), 0.05, math.cos(theta)])
    w = -centre / np.linalg.norm(centre)  # board z towards the camera
    u = np.cross([0.0, 1.0, 0.0], w)
    u /= np.linalg.norm(u)
    B = np.column_stack([u, np.cross(w, u), w]) @ rotation_from_euler(-0.49, -0.26, 0.22)
    truth = Rigid(B, centre)
    P = truth.apply(obj)
    uv, valid = lens.project(P)
    assert valid.all() and (P[:, 2] < 0).sum() >= 10  # corners past 90 degrees
    n_true = truth.rotation[:, 2]
    d_true = float(n_true @ truth.translation)
    chi2 = []
    for seed in range(5):
        rng = np.random.default_rng(seed)
        fit = board_pose_from_corners(lens, obj, uv + rng.normal(0.0, 0.2, uv.shape))
        n, d = fit.plane()
        assert math.degrees(math.acos(min(1.0, float(n @ n_true)))) < 1.0
        assert abs(d - d_true) < 0.01
        np.testing.assert_allclose(fit.board_to_camera.translation, centre, atol=0.03)
        assert 0.15 < fit.rms_px < 0.4  # 0.2 px per axis
        e = np.r_[n - n_true, d - d_true]
        chi2.append(e @ np.linalg.pinv(fit.plane_covariance(), rcond=1e-12) @ e)
    assert np.mean(chi2) < 12.0  # the plane covariance is realistic (3 dof: ~3)
    # exact corners: exact pose
    exact = board_pose_from_corners(lens, obj, uv)
    assert _errors(exact.board_to_camera, truth)[0] < 1e-9
    np.testing.assert_allclose(exact.board_to_camera.translation, centre, atol=1e-9)


def test_board_pose_from_corners_with_every_corner_behind_the_lens_plane() -> None:
    # no corner has z > 0, so a pinhole solvePnP on normalised coordinates cannot start:
    # the initial PnP runs in a virtual camera looking along the corners' mean ray
    lens = default_lens()
    obj = Checkerboard(cols=5, rows=5, square=0.02, width=0.12, height=0.12).corners()
    theta = math.radians(91.3)
    centre = 2.5 * np.array([math.sin(theta) * 0.8, math.sin(theta) * 0.6, math.cos(theta)])
    w = -centre / np.linalg.norm(centre)  # board z towards the camera
    u = np.cross([0.0, 0.0, 1.0], w)
    u /= np.linalg.norm(u)
    B = np.column_stack([u, np.cross(w, u), w]) @ rotation_from_euler(0.3, -0.2, 0.5)
    truth = Rigid(B, centre)
    P = truth.apply(obj)
    uv, valid = lens.project(P)
    assert valid.all() and (P[:, 2] < 0).all()
    fit = board_pose_from_corners(lens, obj, uv)
    assert _errors(fit.board_to_camera, truth)[0] < 1e-8
    np.testing.assert_allclose(fit.board_to_camera.translation, centre, atol=1e-8)


def test_bad_inputs_are_refused() -> None:
    P = np.array([[1.0, 0.0, 0.0], [1.0, 0.5, 0.0]])
    with pytest.raises(ValueError, match="at least 2 laser points"):
        BoardPose(np.array([0.0, 0.0, 1.0]), 1.0, P[:1])
    with pytest.raises(ValueError, match="non-zero"):
        BoardPose(np.zeros(3), 1.0, P)
    pose = BoardPose(np.array([0.0, 0.0, 2.0]), 4.0, P)  # normalised with its distance
    assert pose.distance == 2.0 and pose.normal[2] == 1.0
    data = simulate(6, seed=0, true_planes=True)
    with pytest.raises(ValueError, match="unknown loss"):
        ex.refine(data.poses, data.truth, loss="l1")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="plane_cov"):
        ex.refine(data.poses, data.truth, plane_errors=True)
