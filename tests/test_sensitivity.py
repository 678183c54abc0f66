"""`acq analyze sensitivity` (paper §4.1): the analytic Jacobian against finite
differences, eq. (7) on a hand-computed point, Table 3 against the third-order formula,
the PNGs, and the command on a short log of the simulated rig."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from acq import calibfile, sensitivity
from acq.calibfile import Calibration, CameraCalib
from acq.sensitivity import PARAMS
from acq.transforms import Rigid, rotation_from_euler
from sim.world import default_rig


def _rig_params() -> tuple[np.ndarray, CameraCalib]:
    rig = default_rig()
    cam = CameraCalib(rig.lens, rig.camera_to_laser)
    return sensitivity.params_from_calib(cam), cam


def _street_points(n: int = 400, seed: int = 0) -> np.ndarray:
    """Laser-frame points in the scan plane (z = 0) at 2..20 m, all around."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(-math.pi, math.pi, n)
    r = rng.uniform(2.0, 20.0, n)
    return np.stack([r * np.cos(a), r * np.sin(a), np.zeros(n)], axis=1)


@pytest.mark.parametrize("seed", [0, 1])
def test_jacobian_matches_central_differences(seed: int) -> None:
    p, _ = _rig_params()
    rng = np.random.default_rng(seed)
    # the rig's parameters, and a generic set (non-square pixels, an off-axis pose)
    if seed:
        p = p.copy()
        p[:3] = rng.uniform(-1.0, 1.0, 3)
        p[3:6] = rng.uniform(-0.5, 0.5, 3)
        p[11] *= 1.03
    P = _street_points(300, seed) + rng.normal(0.0, 1.0, (300, 3))
    uv, theta, J = sensitivity.jacobian(P, p)
    uv2, theta2 = sensitivity.project(P, p)
    np.testing.assert_allclose(uv, uv2, rtol=0, atol=1e-9)
    np.testing.assert_allclose(theta, theta2, rtol=0, atol=1e-12)
    steps = np.array([1e-5] * 6 + [1e-6 * p[6]] * 2 + [1e-4] * 2 + [1e-6 * p[10], 1e-6 * p[11]])
    for i, name in enumerate(PARAMS):
        a, b = p.copy(), p.copy()
        a[i] += steps[i]
        b[i] -= steps[i]
        fd = (sensitivity.project(P, a)[0] - sensitivity.project(P, b)[0]) / (2 * steps[i])
        an = J[:, :, i]
        err = np.linalg.norm(an - fd, axis=1) / np.maximum(np.linalg.norm(an, axis=1), 1e-12)
        assert err.max() < 1e-6, (name, err.max())
    assert np.abs(J).max(axis=(0, 1)).min() > 0  # every parameter moves some point


def test_rotation_jacobian_is_the_transforms_convention() -> None:
    angles = (0.3, -1.2, 2.0)
    R, dR = sensitivity.rotation_jacobian(angles)
    np.testing.assert_allclose(R, rotation_from_euler(*angles), atol=1e-15)
    for j in range(3):
        a, b = list(angles), list(angles)
        a[j] += 1e-6
        b[j] -= 1e-6
        fd = (rotation_from_euler(*a) - rotation_from_euler(*b)) / 2e-6
        np.testing.assert_allclose(dR[j], fd, atol=1e-9)


def test_eq7_on_a_hand_computed_point() -> None:
    # R = I, t = (0.1, 0, 0): P_c = (0.9, 0, 1), phi = 0, theta = atan(0.9)
    k1, k2, u0, v0, mu = 1.0, 0.1, 50.0, 40.0, 100.0
    p = np.array([0.0, 0.0, 0.0, 0.1, 0.0, 0.0, k1, k2, u0, v0, mu, mu])
    P = np.array([[1.0, 0.0, 1.0]])
    uv, theta, J = sensitivity.jacobian(P, p)
    th = math.atan(0.9)
    r = k1 * th + k2 * th**3
    assert theta[0] == pytest.approx(th)
    np.testing.assert_allclose(uv[0], [u0 + mu * r, v0], atol=1e-12)
    f = mu * r  # from the principal point (u0, v0) held fixed
    s = sensitivity.sensitivities(uv, J, p, (u0, v0))[0]
    dr = k1 + 3 * k2 * th**2
    dtheta_dx = 1.0 / (0.9**2 + 1.0)  # d atan2(x, z)/dx at z = 1
    expect = {
        "k1": mu * th * k1 / f,
        "k2": mu * th**3 * k2 / f,
        "u0": 1.0 * u0 / f,
        "v0": 0.0,  # the point is on the horizontal through the origin
        "mu_x": r * mu / f,  # = 1
        "mu_y": 0.0,
        "tx": -mu * dr * dtheta_dx * 0.1 / f,
        "ty": 0.0,  # t_y = 0
        "roll": 0.0,  # all angles are 0
    }
    for name, value in expect.items():
        assert s[PARAMS.index(name)] == pytest.approx(value, abs=1e-12), name
    # the printed eq. (8), from pixel (0, 0): f = |uv|, and u0 now counts
    s0 = sensitivity.sensitivities(uv, J, p, (0.0, 0.0))[0]
    f0 = math.hypot(*uv[0])
    assert s0[PARAMS.index("u0")] == pytest.approx(uv[0, 0] / f0 * u0 / f0)
    # the px per sigma: |d(u,v)/dp| sigma
    sig = np.arange(1.0, 13.0)
    shift = sensitivity.pixel_shift(J, sig)[0]
    assert shift[PARAMS.index("k1")] == pytest.approx(mu * th * 7.0)
    assert shift[PARAMS.index("v0")] == pytest.approx(10.0)


def test_points_near_the_origin_are_left_out() -> None:
    p, _ = _rig_params()
    uv = np.array([[p[8] + 0.2, p[9]], [p[8] + 50.0, p[9]]])
    J = np.ones((2, 2, 12))
    s = sensitivity.sensitivities(uv, J, p, (p[8], p[9]))
    assert np.isnan(s[0]).all() and np.isfinite(s[1]).all()


def test_table3_is_monotonic_and_matches_the_third_order_formula() -> None:
    p, _ = _rig_params()
    # the paper's value (mu k2 = 1.21 px) gives the paper's table: 16, 27, 47, 123 m
    paper = p.copy()
    paper[7] = sensitivity.PAPER_THIRD_ORDER_PX / paper[11]
    t = sensitivity.table3(paper, 2.0, 10.0, thresholds_px=(1, 2, 3, 4))
    heights = [row["height_m"] for row in t["thresholds"]]
    np.testing.assert_allclose(heights, [16, 27, 47, 123], rtol=0.05)
    np.testing.assert_allclose(
        [row["theta_deg"] for row in t["thresholds"]], [53.75, 67.75, 77.5, 85.375], atol=0.3
    )
    t = sensitivity.table3(p, 1.5, 8.0)
    rows = t["thresholds"]
    assert all(b["height_m"] > a["height_m"] for a, b in itertools.pairwise(rows))
    assert all(r["theta_from_deg"] < r["theta_deg"] for r in rows)
    for row in rows:  # the error at that height is the threshold
        th = math.atan2(row["height_m"] - 1.5, 8.0)
        e = float(sensitivity.third_order_px(np.array(th), p))
        assert e == pytest.approx(row["error_px"], rel=1e-9)
    errs = [r["error_px"] for r in t["heights"]]
    assert errs == sorted(errs)
    th = math.atan2(30.0 - 1.5, 8.0)
    assert errs[-1] == pytest.approx(p[7] * p[11] * th**3)
    with pytest.raises(ValueError):
        sensitivity.table3(p, 2.0, 0.0)


def test_plot_has_the_size_and_draws_every_series(tmp_path: Path) -> None:
    x = np.linspace(0, 90, 46)
    img = sensitivity.line_plot(
        [("a", x, 1e-3 * (1 + x)), ("b", x, np.full_like(x, 0.5))],
        "title",
        "theta (deg)",
        "value",
        size=(800, 500),
        log_y=True,
    )
    assert img.shape == (500, 800, 3) and img.dtype == np.uint8
    for colour in sensitivity._COLOURS[:2]:
        assert (np.all(img == colour, axis=2)).sum() > 200, colour
    blank = sensitivity.line_plot([], "t", "x", "y", size=(800, 500))
    assert blank.shape == (500, 800, 3)


@pytest.fixture(scope="module")
def rig_files(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """calib.yaml of the simulated rig and a short MCAP log of its scans (written by the
    recorder's own MCAP writer through ``acq.demo``, 2 s)."""
    from acq.demo import run

    out = tmp_path_factory.mktemp("sensitivity_demo")
    assert run(out, seconds=2.0) == 0
    return out / "calib.yaml", out / "demo.mcap"


def test_main_sensitivity_on_a_simulated_log(
    rig_files: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    calib, log = rig_files
    out = tmp_path / "out"
    code = sensitivity.main_sensitivity(calib, [log], out, 2.0, 10.0, False)
    printed = capsys.readouterr().out
    assert code == 0, printed
    for name in PARAMS:
        assert f"  {name} " in printed
    assert "Table 3" in printed
    sizes = {"fig7_rigid.png": (1200, 960), "fig8_camera.png": (1200, 960)}
    sizes["fig9_third_order.png"] = (600, 960)
    for name, (h, w) in sizes.items():
        img = cv2.imread(str(out / name))
        assert img is not None and img.shape[:2] == (h, w), name
        assert (img < 250).any(axis=2).mean() > 0.02, name  # more than a blank canvas
        assert len(np.unique(img.reshape(-1, 3), axis=0)) > 20, name
    report = json.loads((out / "sensitivity.json").read_text())
    assert report["n_points"] > 1000
    assert report["origin"]["name"] == "principal"
    assert [s["param"] for s in report["summary"]] == list(PARAMS)
    by = {s["param"]: s for s in report["summary"]}
    assert by["u0"]["px_per_sigma_max"] == pytest.approx(0.5)  # du/du0 = 1
    assert by["k2"]["median_abs_s"] < by["k1"]["median_abs_s"] / 10  # the paper's point
    assert len(report["table3"]["thresholds"]) == 5
    assert len(report["bins"]["theta_deg"]) == len(report["bins"]["median_abs_s"])


def test_main_sensitivity_json_and_bad_input(
    rig_files: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    calib, log = rig_files
    assert sensitivity.main_sensitivity(calib, [log], tmp_path / "j", 2.0, 10.0, True) == 0
    assert json.loads(capsys.readouterr().out)["table3"]["camera_height_m"] == 2.0
    bad = tmp_path / "bad.yaml"
    bad.write_text("version: 1\ncameras: {camera: {model: equidistant, fxx: 1}}\n")
    assert sensitivity.main_sensitivity(bad, [log], tmp_path / "b", 2.0, 10.0, False) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "bad.yaml" in err
    assert (
        sensitivity.main_sensitivity(calib, [tmp_path / "nope.mcap"], tmp_path, 2, 10, False) == 2
    )
    assert capsys.readouterr().err.count("\n") == 1
    assert sensitivity.main_sensitivity(calib, [log], tmp_path / "c", 2.0, 0.0, False) == 2
    # a camera 500 m above the scan plane, looking up: every laser point is behind it
    cam = calibfile.load(calib).camera()
    away = Rigid(np.eye(3), np.array([0.0, 0.0, 500.0]))
    far = tmp_path / "far.yaml"
    calibfile.save(Calibration(cameras={"camera": CameraCalib(cam.model, away)}), far)
    assert sensitivity.main_sensitivity(far, [log], tmp_path / "f", 2.0, 10.0, False) == 1
