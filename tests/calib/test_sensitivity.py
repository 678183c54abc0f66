"""`acq analyze sensitivity` (paper §4.1): the analytic Jacobian against finite
differences, eq. (7) on a hand-computed point, Table 3 against the third-order formula,
the PNGs, and the command on a short log of the simulated rig."""

from __future__ import annotations

import itertools
import json
import logging
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from acq.calib import plots, sensitivity
from acq.calib.sensitivity import PARAMS
from acq.camera import calibfile
from acq.camera.calibfile import Calibration, CalibStd, CameraCalib
from acq.geometry.rotations import (
    matrix_from_rotvec,
    rotation_from_euler,
    rotation_to_euler,
    skew,
)
from acq.geometry.transforms import Rigid
from acq.sim.world import default_rig
from tests.cli_calls import analyze_sensitivity
from tests.log_rewrite import corrupt_chunk, rewrite


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
    img = plots.line_plot(
        [("a", x, 1e-3 * (1 + x)), ("b", x, np.full_like(x, 0.5))],
        "title",
        "theta (deg)",
        "value",
        size=(800, 500),
        log_y=True,
    )
    assert img.shape == (500, 800, 3) and img.dtype == np.uint8
    for colour in plots.PALETTE[:2]:
        assert (np.all(img == colour, axis=2)).sum() > 200, colour
    blank = plots.line_plot([], "t", "x", "y", size=(800, 500))
    assert blank.shape == (500, 800, 3)


@pytest.fixture(scope="module")
def rig_files(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """calib.yaml of the simulated rig and a short MCAP log of its drive (1.5 s, written
    as the recorder writes, by ``acq.sim.drive_log``: no live devices, so not a real-time
    test)."""
    from acq.sim.drive_log import write_drive_log

    out = tmp_path_factory.mktemp("sensitivity_drive")
    truth = write_drive_log(out, 1.5, pattern_at=None)
    calibfile.save(truth.calibration, out / "calib.yaml")
    return out / "calib.yaml", truth.files[0]


def test_main_sensitivity_on_a_simulated_log(
    rig_files: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    calib, log = rig_files
    out = tmp_path / "out"
    code = analyze_sensitivity(calib, [log], out, 2.0, 10.0, False)
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
    assert analyze_sensitivity(calib, [log], tmp_path / "j", 2.0, 10.0, True) == 0
    assert json.loads(capsys.readouterr().out)["table3"]["camera_height_m"] == 2.0
    bad = tmp_path / "bad.yaml"
    bad.write_text("version: 1\ncameras: {camera: {model: equidistant, fxx: 1}}\n")
    assert analyze_sensitivity(bad, [log], tmp_path / "b", 2.0, 10.0, False) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "bad.yaml" in err
    assert analyze_sensitivity(calib, [tmp_path / "nope.mcap"], tmp_path, 2, 10, False) == 2
    assert capsys.readouterr().err.count("\n") == 1
    assert analyze_sensitivity(calib, [log], tmp_path / "c", 2.0, 0.0, False) == 2
    # a camera 90 m above the scan plane, looking up: every laser point is behind it
    cam = calibfile.load(calib).camera()
    away = Rigid(np.eye(3), np.array([0.0, 0.0, 90.0]))
    far = tmp_path / "far.yaml"
    calibfile.save(Calibration(cameras={"camera": CameraCalib(cam.model, away)}), far)
    assert analyze_sensitivity(far, [log], tmp_path / "f", 2.0, 10.0, False) == 1


def test_main_sensitivity_says_it_skipped_a_corrupt_chunk(
    rig_files: tuple[Path, Path], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    calib, log = rig_files
    [copy], _ = rewrite([log], tmp_path, chunk_size=1 << 18)
    corrupt_chunk(copy, 1)
    with caplog.at_level(logging.WARNING):
        assert analyze_sensitivity(calib, [copy], tmp_path / "out", 2.0, 10.0, True) == 0
    [line] = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert line.startswith(f"{copy}: 1 corrupt chunk skipped (") and "messages lost)" in line


# --- sigma from the calibration's std ------------------------------------------------------


def _spd(seed: int, scale: float) -> np.ndarray:
    """A full (3,3) covariance, correlations included, of about ``scale``² ."""
    A = np.random.default_rng(seed).normal(0.0, scale, (3, 3))
    return A @ A.T + np.eye(3) * scale**2


@pytest.mark.parametrize("generic", [False, True])
def test_rotation_sigma_is_the_shift_of_a_one_sigma_rotation_about_each_axis(
    generic: bool,
) -> None:
    """The rig sits near pitch -90 deg (roll and yaw turn about the same axis): each
    angle's sigma moves points as one sigma of the rotation about that angle's axis, checked
    with finite rotations of R (not through Euler angles)."""
    p, _ = _rig_params()
    if generic:
        p = p.copy()
        p[:3] = (0.3, -1.2, 2.0)
    R = rotation_from_euler(*p[:3])
    axes, rate = sensitivity.rotation_axes(p[:3])
    np.testing.assert_allclose(rate, 1.0, atol=1e-12)  # unit rates for Rz Ry Rx
    np.testing.assert_allclose(axes[2], [0.0, 0.0, 1.0], atol=1e-12)  # yaw: laser z
    np.testing.assert_allclose(axes[0], R[:, 0], atol=1e-12)  # roll: the camera's x
    if not generic:
        assert abs(axes[0] @ axes[2]) > 0.999  # gimbal lock: roll ~ yaw
    for i in range(3):  # an Euler step is a rotation about a_i (laser frame)
        d = np.zeros(3)
        d[i] = 1e-6
        fd = (rotation_from_euler(*(p[:3] + d)) - rotation_from_euler(*(p[:3] - d))) / 2e-6
        np.testing.assert_allclose(fd, rate[i] * skew(axes[i]) @ R, atol=1e-8)
    cov_w = _spd(3, math.radians(0.05))
    sig = sensitivity.rotation_sigma(p[:3], cov_w)
    np.testing.assert_allclose(sig, [math.sqrt(a @ cov_w @ a) for a in axes], rtol=1e-12)  # rate 1
    P = _street_points(3000, 4)
    uv, theta, J = sensitivity.jacobian(P, p)
    seen = theta < math.radians(92.5)  # in the lens's field of view
    P, uv, J = P[seen], uv[seen], J[seen]
    full = np.r_[sig, np.zeros(9)]
    linear = sensitivity.pixel_shift(J, full)[:, :3]
    for i in range(3):
        Ri = matrix_from_rotvec(axes[i] * sig[i] * rate[i]) @ R
        q = p.copy()
        q[:3] = rotation_to_euler(Ri)
        moved = np.linalg.norm(sensitivity.project(P, q)[0] - uv, axis=1)
        ok = np.isfinite(moved) & np.isfinite(linear[:, i]) & (linear[:, i] > 0.01)
        assert ok.sum() > 100
        np.testing.assert_allclose(moved[ok], linear[ok, i], rtol=0.01)
    # the std of a diagonal covariance: an angle's sigma lies between the smallest and
    # the largest (no blow-up at the gimbal lock, unlike Euler-angle std)
    s = np.radians([0.05, 0.04, 0.06])
    sig = sensitivity.rotation_sigma(p[:3], np.diag(s**2))
    assert (sig >= s.min() - 1e-15).all() and (sig <= s.max() + 1e-15).all()
    assert sig[2] == pytest.approx(s[2])  # yaw turns about the laser's z


STD_VALUES: dict[str, Any] = {  # no cy: v0 keeps its default
    "fx": 0.2,
    "fy": 0.3,
    "cx": 0.15,
    "k": (2e-3, 4e-3, 3e-3, 1e-3),
    "rotation_deg": (0.05, 0.04, 0.06),
    "translation_m": (0.002, 0.003, 0.004),
}


def _std(scale: float = 1.0) -> CalibStd:
    """:data:`STD_VALUES` times ``scale``."""
    return CalibStd(
        **{
            n: tuple(scale * x for x in v) if isinstance(v, tuple) else scale * v
            for n, v in STD_VALUES.items()
        }
    )


STD = _std()


def test_sigma_from_the_calibrations_std() -> None:
    p, cam = _rig_params()
    cam = replace(cam, std=STD)
    m = cam.model
    sig, src = sensitivity.choose_sigma(p, cam)
    by = dict(zip(PARAMS, sig, strict=True))
    assert dict(zip(PARAMS, src, strict=True)) == {
        **dict.fromkeys(PARAMS, "calib"),
        "v0": "default",
    }
    assert by["v0"] == 0.5 and by["u0"] == 0.15
    assert by["k1"] / p[6] == pytest.approx(0.2 / m.fx)
    assert by["mu_x"] / p[10] == pytest.approx(0.2 / m.fx)
    assert by["mu_y"] / p[11] == pytest.approx(0.3 / m.fy)
    assert by["k2"] == pytest.approx(p[6] * 2e-3)
    np.testing.assert_allclose([by["tx"], by["ty"], by["tz"]], STD.translation_m)
    expect = sensitivity.rotation_sigma(p[:3], np.diag(np.radians(STD.rotation_deg) ** 2))
    np.testing.assert_allclose([by["roll"], by["pitch"], by["yaw"]], expect)
    # mu_x and mu_y move a point as one sigma of fx, fy does in u = u0 + fx (theta +
    # k[0] theta³) cos(phi), v = v0 + fy (...) sin(phi); k1 as a relative sigma_fx of both
    P = _street_points(300, 5)
    _, theta, J = sensitivity.jacobian(P, p)
    shift = sensitivity.pixel_shift(J, sig)
    g = theta + p[7] / p[6] * theta**3
    cos, sin = J[:, 0, 10] / (p[6] * g), J[:, 1, 11] / (p[6] * g)  # du/dmu_x = r cos(phi)
    np.testing.assert_allclose(shift[:, 10], np.abs(cos) * g * 0.2, rtol=1e-9)
    np.testing.assert_allclose(shift[:, 11], np.abs(sin) * g * 0.3, rtol=1e-9)
    k1_px = theta * 0.2 / m.fx * np.hypot(m.fx * cos, m.fy * sin)
    np.testing.assert_allclose(shift[:, 6], k1_px, rtol=1e-9)
    # --sigma overrides come first; without std every sigma is the default
    sig2, src2 = sensitivity.choose_sigma(p, cam, {"tx": 0.01, "v0": 0.2})
    assert (src2[3], src2[9]) == ("override", "override") and (sig2[3], sig2[9]) == (0.01, 0.2)
    bare, src3 = sensitivity.choose_sigma(p, replace(cam, std=CalibStd()))
    np.testing.assert_array_equal(bare, sensitivity.default_sigma(p))
    assert set(src3) == {"default"}


def test_main_sensitivity_uses_the_stored_std(
    rig_files: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    calib, log = rig_files
    cal = calibfile.load(calib)
    name, cam = next(iter(cal.cameras.items()))
    runs = {}
    for k in (1.0, 2.0):
        s = _std(k)
        path = tmp_path / f"std{k:g}.yaml"
        calibfile.save(Calibration(cameras={name: replace(cam, std=s)}), path)
        assert analyze_sensitivity(path, [log], tmp_path / f"o{k:g}", json_out=True) == 0
        runs[k] = json.loads(capsys.readouterr().out)
    one = {s["param"]: s for s in runs[1.0]["summary"]}
    two = {s["param"]: s for s in runs[2.0]["summary"]}
    for n in PARAMS:
        if n == "v0":  # not in the std: the default, the same in both runs
            assert one[n]["sigma_source"] == "default" and one[n]["sigma"] == 0.5
            assert two[n]["px_per_sigma_max"] == one[n]["px_per_sigma_max"]
            continue
        assert one[n]["sigma_source"] == "calib", n
        for key in ("px_per_sigma_max", "px_per_sigma_median_theta", "px_per_sigma_max_theta"):
            assert two[n][key] == pytest.approx(2 * one[n][key], rel=1e-9), (n, key)
    assert one["u0"]["px_per_sigma_max"] == pytest.approx(0.15)  # du/du0 = 1
    assert one["tx"]["sigma"] == pytest.approx(0.002)
    notes = runs[1.0]["notes"]
    assert any("calib.yaml's std: roll" in s and "defaults: v0" in s for s in notes)
    assert any(s.startswith("rotation sigma: one std of the rotation about") for s in notes)
    # the text report: where each sigma came from; --sigma overrides the std
    path = tmp_path / "std1.yaml"
    assert analyze_sensitivity(path, [log], tmp_path / "t", sigma={"tx": 0.01}) == 0
    text = capsys.readouterr().out
    row = {line.split()[0]: line.split() for line in text.splitlines() if line.startswith("  ")}
    assert row["v0"][5] == "default" and row["u0"][5] == "calib" and row["tx"][5] == "override"
    assert row["tx"][3:5] == ["10", "mm"] and "--sigma: tx" in text


def test_sigma_flag(capsys: pytest.CaptureFixture[str]) -> None:
    from acq import cli

    base = ["analyze", "sensitivity", "x.mcap", "--calib", "c.yaml"]
    args = cli.build_parser().parse_args([*base, "--sigma", "yaw=0.002", "--sigma", "tx=1e-3"])
    assert args.sigma == [("yaw", 0.002), ("tx", 0.001)]
    assert cli.build_parser().parse_args(base).sigma is None
    for bad, word in (("yaw", "NAME=VALUE"), ("yawn=1", "unknown parameter"), ("tx=-1", ">= 0")):
        with pytest.raises(SystemExit):
            cli.build_parser().parse_args([*base, "--sigma", bad])
        assert word in capsys.readouterr().err
