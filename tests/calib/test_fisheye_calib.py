"""`acq calibrate fisheye`: calib.yaml from the image circle (f = r / theta_max), existing
files kept, the overlay and JSON, the pitfalls reported; the Kannala–Brandt board fit
past 90 degrees; the real images against their checkerboard reference."""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

from acq import camera_models  # the API name of ARCHITECTURE.md
from acq.calib import fisheye_calib, image_circle
from acq.camera import calibfile
from acq.camera.calibfile import CalibFileError, Calibration, CalibStd, CameraCalib
from acq.camera.camera_models import Equidistant, KannalaBrandt
from acq.geometry.rotations import rotation_from_euler
from acq.geometry.transforms import Rigid
from acq.sim.fisheye_images import CircleTruth, fisheye_image
from acq.sim.world import default_lens
from tests.cli_calls import calibrate_fisheye

THETA_MAX = math.radians(185.0) / 2
REFERENCE_PP = (384.8, 240.0)  # ../shared/data/README.md, fisheye/
REFERENCE_F = 209.0


@pytest.fixture(scope="module")
def sim_png(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, CircleTruth]:
    img, truth = fisheye_image(cx=386.6, cy=294.3, radius=274.2, rim=0.3, edge_width=2.0)
    path = tmp_path_factory.mktemp("img") / "frame.png"
    cv2.imwrite(str(path), img)
    return path, truth


def test_writes_the_equidistant_model_from_the_circle(
    sim_png: tuple[Path, CircleTruth], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path, truth = sim_png
    out = tmp_path / "calib.yaml"
    assert calibrate_fisheye([path], 185.0, out) == 0
    cam = camera_models.load(out)
    assert isinstance(cam, Equidistant)
    assert (cam.width, cam.height) == (780, 582)
    assert cam.f == pytest.approx(truth.radius / THETA_MAX, abs=0.3 / THETA_MAX)
    assert math.hypot(cam.cx - truth.cx, cam.cy - truth.cy) < 0.2
    written = calibfile.load(out, intrinsics_only=True).camera("camera")
    assert written.method == "image_circle"
    # the pose is not known yet: written without one, not as the identity
    assert written.extrinsics is None and "camera_to_laser" not in out.read_text()
    with pytest.raises(CalibFileError, match=r"cameras\.camera\.camera_to_laser: required key"):
        calibfile.load(out)
    text = capsys.readouterr().out
    assert "f = r / theta_max" in text and "subpixel" in text
    overlay = cv2.imread(str(tmp_path / "calib_circle.png"))
    assert overlay is not None and overlay.shape == (582, 780, 3)
    # the detected circle is drawn in green on the overlay, on the rim
    px = overlay[round(truth.cy), round(truth.cx + truth.radius)]
    assert px[1] > 150 and px[1] > px[2] + 50


def test_json_has_centre_radius_estimators_and_spread(
    sim_png: tuple[Path, CircleTruth], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path, truth = sim_png
    png = tmp_path / "o.png"
    rc = calibrate_fisheye(
        [path], 190.0, tmp_path / "c.yaml", camera="left", json_out=True, overlay=png
    )
    assert rc == 0 and png.exists()
    d = json.loads(capsys.readouterr().out)
    c = d["circle"]
    assert c["cx"] == pytest.approx(truth.cx, abs=0.2) and c["radius"] == pytest.approx(
        truth.radius, abs=0.3
    )
    assert set(c["estimators"]) == set(image_circle.ESTIMATORS)
    assert {"centre_px", "radius_px"} == set(c["spread"])
    assert d["camera"] == "left" and d["model"]["model"] == "equidistant"
    assert d["model"]["fx"] == pytest.approx(c["radius"] / math.radians(95.0), abs=0.01)
    assert d["model"]["fov_deg"] == 190.0


def test_the_circle_alone_says_what_f_rests_on(
    sim_png: tuple[Path, CircleTruth], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """f = r / theta_max holds only for the stated aperture and an equidistant lens: the
    result and calib.yaml say so, with f for an aperture 5 degrees off (px/rad); a board
    fit, which checks both, drops the note."""
    path, _ = sim_png
    out = tmp_path / "calib.yaml"
    assert calibrate_fisheye([path], 185.0, out, json_out=True) == 0
    d = json.loads(capsys.readouterr().out)
    r = d["circle"]["radius"]
    assumed = d["circle_model_assumes"]
    assert assumed["fov_deg"] == 185.0 and assumed["tolerance_deg"] == 5.0
    lo, hi = assumed["f_range_px"]
    assert lo == pytest.approx(r / math.radians(95.0), abs=0.01)
    assert hi == pytest.approx(r / math.radians(90.0), abs=0.01)
    assert calibrate_fisheye([path], 185.0, out) == 0
    text = capsys.readouterr().out
    note = calibfile.load(out, intrinsics_only=True).camera().note
    assert note == assumed["note"] and note in text.splitlines()
    assert f"f {lo:.1f}..{hi:.1f} px/rad" in note and "equidistant" in note
    assert "aperture of 185 deg" in note and "--board" in note
    # the intrinsics replaced by a board's fit: the note goes with them
    kb = KannalaBrandt(780, 582, 200.0, 200.2, 390.0, 291.0, (0.01, 0.0, 0.0, 0.0))
    calib, _, _ = fisheye_calib.update_calibration(out, None, kb, "board")
    calibfile.save(calib, out)
    assert calibfile.load(out, intrinsics_only=True).camera().note == ""
    assert "note" not in out.read_text()
    # the circle again over the board's fit: how far the two f are apart is said
    assert calibrate_fisheye([path], 185.0, out) == 0
    f = d["model"]["fx"]
    assert (
        f"warning: camera 'camera': f {f:.2f} px/rad (image_circle) replaces 200.10 (board) "
        f"in {out}, {100 * (f / 200.1 - 1):+.1f} %"
    ) in capsys.readouterr().err.splitlines()


def test_circle_check_splits_the_gap_and_says_when_the_rim_is_out_of_reach() -> None:
    """An equidistant lens whose true aperture is 180 deg, stated as 185: the circle's f
    is off by the aperture alone; a board model that puts the rim past 180 deg off the
    axis cannot say where the rim is, and says so (no warning, no made-up angle)."""
    truth = KannalaBrandt(780, 582, 180.0, 180.0, 390.0, 291.0, (0.0, 0.0, 0.0, 0.0), 180.0)
    radius = 180.0 * math.pi / 2
    circle = Equidistant.from_f(radius / math.radians(92.5), 390.0, 291.0, 780, 582, 185.0)
    fit = fisheye_calib.BoardFit(truth, 0.1, [0.1], [0], {}, 60.0, [])
    check = fisheye_calib.circle_check(circle, radius, fit)
    assert check.rim_deg == pytest.approx(90.0)
    assert check.off_percent == pytest.approx(100 * (90 / 92.5 - 1))
    assert check.aperture_percent == pytest.approx(check.off_percent)
    assert check.equidistance_percent == pytest.approx(0.0, abs=1e-9)
    assert "at 90.0 deg off the axis (aperture 180.0 deg against --fov 185)" in check.line()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        far = fisheye_calib.circle_check(circle, 4 * 180.0, fit)
    assert math.isnan(far.rim_deg) and "does not reach the rim" in far.line()


def test_keeps_other_cameras_and_the_extrinsics(
    sim_png: tuple[Path, CircleTruth], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path, truth = sim_png
    extr = Rigid(rotation_from_euler(0.1, -0.2, 0.3), np.array([0.4, -0.1, 0.2]))
    old = Equidistant.from_f(150.0, 400.0, 280.0, 780, 582)
    other = KannalaBrandt(640, 480, 200.0, 200.0, 320.0, 240.0, (0.01, 0, 0, 0))
    calib = Calibration(
        laser="utm",
        cameras={
            "left": CameraCalib(old, extr, 0.0125, "manual"),
            "right": CameraCalib(other, Rigid.identity(), 0.0, "board"),
        },
        laser_to_vehicle=Rigid(np.eye(3), np.array([0.0, 0.0, 2.2])),
    )
    out = tmp_path / "calib.yaml"
    calibfile.save(calib, out)
    # two cameras and none named: refused, file untouched
    before = out.read_text()
    assert calibrate_fisheye([path], 185.0, out) == 2
    assert "--camera" in capsys.readouterr().err
    assert out.read_text() == before
    assert calibrate_fisheye([path], 185.0, out, camera="left") == 0
    new = calibfile.load(out)
    assert new.laser == "utm" and new.laser_to_vehicle is not None
    assert np.allclose(new.laser_to_vehicle.translation, [0, 0, 2.2])
    left = new.camera("left")
    assert np.allclose(left.camera_to_laser.matrix(), extr.matrix())
    assert left.time_offset_s == 0.0125 and left.method == "image_circle"
    assert left.model.cx == pytest.approx(truth.cx, abs=0.2)
    assert new.camera("right").to_dict() == calib.camera("right").to_dict()


def test_truncated_circle_warns_that_the_barycentre_is_biased(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    img, truth = fisheye_image(cx=392.0, cy=288.5, radius=318.0, seed=2, t=5.0)
    path = tmp_path / "cut.png"
    cv2.imwrite(str(path), img)
    assert calibrate_fisheye([path], 185.0, tmp_path / "c.yaml") == 0
    out, err = capsys.readouterr()
    assert "barycentre is biased" in err and "[biased: the circle is truncated]" in out
    cam = camera_models.load(tmp_path / "c.yaml")
    assert cam.fx == pytest.approx(truth.radius / THETA_MAX, abs=0.3 / THETA_MAX)


def test_ellipse_writes_non_square_pixels(tmp_path: Path) -> None:
    img, truth = fisheye_image(radius=258.0, aspect=1.05, seed=3, t=8.0)
    path = tmp_path / "e.png"
    cv2.imwrite(str(path), img)
    out = tmp_path / "c.yaml"
    assert calibrate_fisheye([path], 185.0, out, ellipse=True) == 0
    cam = camera_models.load(out)
    assert type(cam) is KannalaBrandt and cam.k == (0.0, 0.0, 0.0, 0.0)
    assert cam.fx == pytest.approx(truth.a / THETA_MAX, abs=0.3 / THETA_MAX)
    assert cam.fy == pytest.approx(truth.b / THETA_MAX, abs=0.3 / THETA_MAX)


def test_bad_input_exits_2_with_one_line(
    sim_png: tuple[Path, CircleTruth], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path, _ = sim_png
    out = tmp_path / "c.yaml"
    cases = [
        ([tmp_path / "missing.png"], 185.0, None, "missing.png"),
        ([path], 0.0, None, "--fov"),
        ([path], 185.0, "8x6", "COLSxROWSxSQUARE"),
    ]
    for images, fov, board, word in cases:
        assert calibrate_fisheye(images, fov, out, board=board) == 2
        err = capsys.readouterr().err
        assert word in err and err.count("\n") == 1
    out.write_text("version: 1\ncameras: {camera: {model: equidistant}}\n")
    assert calibrate_fisheye([path], 185.0, out) == 2
    assert "cameras.camera.image_size: required key missing" in capsys.readouterr().err


def test_an_image_that_is_no_fisheyes_exits_2_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    fisheye = tmp_path / "fisheye.png"
    cv2.imwrite(str(fisheye), fisheye_image(640, 480, 320.0, 240.0, radius=220.0, seed=5)[0])
    grey = tmp_path / "grey.png"
    cv2.imwrite(str(grey), np.full((480, 640, 3), 128, np.uint8))
    board = tmp_path / "board.png"
    v, u = np.mgrid[0:480, 0:640]
    cv2.imwrite(str(board), (((u // 40 + v // 40) % 2) * 255).astype(np.uint8))
    dot = tmp_path / "dot.png"
    cv2.imwrite(str(dot), np.full((1, 1), 200, np.uint8))
    text, empty = tmp_path / "text.png", tmp_path / "empty.png"
    text.write_text("not an image\n")
    empty.write_bytes(b"")
    out = tmp_path / "c.yaml"
    cases = [
        ([fisheye, grey], f"{grey}: no image circle found: no dark surround"),
        ([board], f"{board}: no image circle found: "),
        ([dot], f"{dot}: no image circle found: 1x1 px is too small"),
        ([text], f"{text}: cannot read as an image"),
        ([empty], f"{empty}: cannot read as an image"),
        ([tmp_path], f"{tmp_path}: a directory, not an image"),
    ]
    for images, line in cases:
        assert calibrate_fisheye(images, 185.0, out) == 2, line
        err = capsys.readouterr().err
        assert err.startswith(f"acq calibrate fisheye: {line}") and err.count("\n") == 1, err
        assert not out.exists()
    assert not out.with_name("c_circle.png").exists()
    assert fisheye_calib.parse_board("8x6x0.117") == fisheye_calib.BoardSpec(8, 6, 0.117)


# --- the Kannala–Brandt board fit -------------------------------------------------------


def board_views(lens: KannalaBrandt) -> tuple[np.ndarray, list[np.ndarray], float]:
    """An 8x6 board (117 mm) in six poses, the last reaching past 90 degrees off axis."""
    obj = fisheye_calib.BoardSpec(8, 6, 0.117).object_points()
    obj_c = obj - obj.mean(axis=0)
    poses = [
        (0, 0, 1.0, (0.3, -0.2, 0.1)),
        (35, 20, 0.9, (0.2, 0.3, 0)),
        (55, 140, 1.0, (-0.3, 0.2, 0.5)),
        (70, 250, 1.2, (0.4, 0.1, 0.2)),
        (82, 330, 1.6, (0.9, 0.0, 0.0)),
        (80, 90, 2.0, (0.0, 0.9, 0.3)),
    ]
    views, theta_max = [], 0.0
    for th_deg, ph_deg, dist, tilt in poses:
        th, ph = math.radians(th_deg), math.radians(ph_deg)
        d = np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])
        up = [0.0, 0.0, 1.0] if abs(d[2]) < 0.9 else [1.0, 0.0, 0.0]
        x = np.cross(up, -d)
        x /= np.linalg.norm(x)
        R = np.stack([x, np.cross(-d, x), -d], axis=1) @ rotation_from_euler(*tilt)
        P = obj_c @ R.T + d * dist
        uv, valid = lens.project(P)
        assert valid.all()
        theta_max = max(
            theta_max, float(np.degrees(np.arctan2(np.hypot(P[:, 0], P[:, 1]), P[:, 2])).max())
        )
        views.append(uv)
    return obj, views, theta_max


def test_kannala_brandt_fit_recovers_the_lens_past_90_degrees() -> None:
    lens = default_lens()  # the simulator's lens, k1..k4 not zero
    obj, views, theta_max = board_views(lens)
    assert theta_max > 90.0
    rng = np.random.default_rng(0)
    noisy = [v + rng.normal(0.0, 0.1, v.shape) for v in views]
    init = Equidistant.from_f(160.0, 395.0, 287.0, 780, 582)  # a rough circle estimate
    fit = fisheye_calib.fit_kannala_brandt(obj, noisy, init)
    assert fit.rms_px == pytest.approx(0.1 * math.sqrt(2), rel=0.15)
    assert fit.max_theta_deg > 90.0
    m = fit.model
    assert math.hypot(m.cx - lens.cx, m.cy - lens.cy) < 0.6
    # the image radius of every angle up to the rim within half a pixel of the truth
    th = np.linspace(0.0, lens.theta_max, 200)
    assert np.max(np.abs(m.fx * m.distort_theta(th) - lens.fx * lens.distort_theta(th))) < 0.5
    # and the fit's own projection agrees with the reference model past 90 degrees
    P = np.array([[1.0, 0.2, -0.05], [-0.3, 1.0, -0.02]])
    intr = np.array([m.fx, m.fy, m.cx, m.cy, *m.k])
    assert np.allclose(fisheye_calib.project_kb(intr, P), m.project(P)[0])


def test_kannala_brandt_fit_std_matches_its_errors() -> None:
    """The fit's standard deviations (calib.yaml's std) are those of its errors: over
    seeds, the errors of fx, fy, cx, cy, k1..k4 divided by their std have an RMS near 1."""
    lens = default_lens()
    obj, views, _ = board_views(lens)
    init = Equidistant.from_f(160.0, 395.0, 287.0, 780, 582)
    truth = {"fx": lens.fx, "fy": lens.fy, "cx": lens.cx, "cy": lens.cy}
    truth |= {f"k{i + 1}": k for i, k in enumerate(lens.k)}
    z = []
    for seed in range(8):
        rng = np.random.default_rng(100 + seed)
        fit = fisheye_calib.fit_kannala_brandt(
            obj, [v + rng.normal(0.0, 0.2, v.shape) for v in views], init
        )
        m = fit.model
        got = {"fx": m.fx, "fy": m.fy, "cx": m.cx, "cy": m.cy}
        got |= {f"k{i + 1}": k for i, k in enumerate(m.k)}
        z += [(got[n] - truth[n]) / fit.sigma[n] for n in truth]
        std = fit.std()
        assert std.k is not None and std.rotation_deg is None and std.translation_m is None
        assert std.fx == pytest.approx(fit.sigma["fx"], rel=5e-3)
        assert std.k[3] == pytest.approx(fit.sigma["k4"], rel=5e-3)
    rms = math.sqrt(float(np.mean(np.square(z))))
    print(f"RMS of error / std over 8 seeds x 8 intrinsics: {rms:.2f}")
    assert 0.7 < rms < 1.4


def test_keeps_the_extrinsics_std_and_replaces_the_intrinsics(
    sim_png: tuple[Path, CircleTruth], tmp_path: Path
) -> None:
    path, _ = sim_png
    extr_std = CalibStd(rotation_deg=(0.05, 0.04, 0.06), translation_m=(0.002, 0.003, 0.002))
    old_std = extr_std.merged(CalibStd(fx=0.3, fy=0.3, cx=0.2, cy=0.2), CalibStd.INTRINSICS)
    extr = Rigid(rotation_from_euler(0.1, -0.2, 0.3), np.array([0.4, -0.1, 0.2]))
    old = Equidistant.from_f(150.0, 400.0, 280.0, 780, 582)
    out = tmp_path / "calib.yaml"
    calibfile.save(Calibration(cameras={"left": CameraCalib(old, extr, 0.0, "x", old_std)}), out)
    # the circle writes no intrinsics' std: the old ones (of other values) are dropped
    assert calibrate_fisheye([path], 185.0, out) == 0
    assert calibfile.load(out).camera("left").std == extr_std
    # a board fit's std replaces the intrinsics' part only (extrinsics' part in it ignored)
    kb = KannalaBrandt(780, 582, 170.0, 170.2, 390.0, 291.0, (0.01, 0.0, 0.0, 0.0))
    new = CalibStd(fx=0.1, fy=0.1, cx=0.05, cy=0.06, k=(1e-3, 2e-3, 3e-3, 4e-3))
    calib, name, _ = fisheye_calib.update_calibration(
        out, None, kb, "board", new.merged(CalibStd(rotation_deg=(9, 9, 9)), ["rotation_deg"])
    )
    assert name == "left"
    assert calib.camera().std == extr_std.merged(new, CalibStd.INTRINSICS)
    calib, _, _ = fisheye_calib.update_calibration(tmp_path / "new.yaml", None, kb, "b", new)
    assert calib.camera().std == new


# --- the real images --------------------------------------------------------------------


def real_paths(shared_dir: Path) -> list[Path]:
    folder = shared_dir / "data" / "fisheye"
    paths = sorted(folder.glob("Fisheye2_*.jpg"))
    if not paths:
        pytest.skip(f"{folder} has no Fisheye2_*.jpg: the real fisheye images are not here")
    return paths


def test_real_images_circle_then_board(
    shared_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    paths = real_paths(shared_dir)
    out = tmp_path / "calib.yaml"
    rc = calibrate_fisheye(paths, 185.0, out, json_out=True, board="8x6x0.117")
    assert rc == 0
    d = json.loads(capsys.readouterr().out)
    c = d["circle"]
    assert math.hypot(c["cx"] - REFERENCE_PP[0], c["cy"] - REFERENCE_PP[1]) < 2.0
    assert c["truncated"] == ["top", "bottom"]
    # f from the circle is the rim's chord r / theta_max: this lens compresses the rim
    # (k1 < 0), so it is well below the board's central f
    f_circle = d["circle_model"]["fx"]
    assert 170.0 < f_circle < 190.0
    b = d["board"]
    assert b["views"] == [0, 1, 2, 3, 4]
    assert b["rms_px"] < 0.3
    assert math.hypot(b["cx"] - REFERENCE_PP[0], b["cy"] - REFERENCE_PP[1]) < 1.5
    assert b["fx"] == pytest.approx(REFERENCE_F, rel=0.01)
    assert b["fy"] == pytest.approx(REFERENCE_F, rel=0.01)
    # the paper's 3-parameter model does not describe this lens: over the board's angles
    # it is tens of pixels away from the board's model (see Table 3 for the paper's lens)
    assert b["circle_model_gap_px"] > 10.0
    # how far the circle's f is off, and why: the aperture is about right (the rim at
    # ~92 deg), the lens is not equidistant
    check = d["circle_check"]
    assert check["f_circle_px"] == pytest.approx(f_circle, abs=1e-3)
    assert check["f_board_px"] == pytest.approx(REFERENCE_F, rel=0.01)
    assert -16.0 < check["off_percent"] < -12.0
    assert abs(check["aperture_percent"]) < 2.0 and check["equidistance_percent"] < -10.0
    whole = (1 + check["aperture_percent"] / 100) * (1 + check["equidistance_percent"] / 100)
    assert whole == pytest.approx(1 + check["off_percent"] / 100, abs=1e-4)
    assert 2 * check["rim_deg"] == pytest.approx(185.0, abs=4.0)
    assert check["gap_px"] == b["circle_model_gap_px"]
    assert calibfile.load(out, intrinsics_only=True).camera().note == ""  # checked
    cam = camera_models.load(out)
    assert type(cam) is KannalaBrandt and cam.k[0] < 0
    # the fit's standard deviations are in calib.yaml (3 significant digits)
    std = calibfile.load(out, intrinsics_only=True).camera().std
    assert (std.fx, std.fy, std.cx, std.cy) == tuple(
        b["sigma"][n] for n in ("fx", "fy", "cx", "cy")
    )
    assert std.k == tuple(b["sigma"][f"k{i}"] for i in range(1, 5))
    assert std.rotation_deg is None and 0 < std.cx < 0.5
    # the board's lens puts the circle's rim at about half the 185-degree aperture
    theta_rim = float(cam.undistort_theta(np.array([c["radius"] / cam.fx]))[0])
    assert math.degrees(2 * theta_rim) == pytest.approx(185.0, abs=4.0)


def test_a_wrong_board_size_on_the_real_images_names_the_boards(
    shared_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The real images show an 8x6 board, which the lens cuts and bends: a 9x7 --board is
    bad input, answered with the size they show; nothing is written."""
    paths = real_paths(shared_dir)
    out = tmp_path / "calib.yaml"
    assert calibrate_fisheye(paths, 185.0, out, board="9x7x0.117") == 2
    assert capsys.readouterr().err == (
        "acq calibrate fisheye: --board 9x7x0.117: no image shows the 9x7 board; the images "
        "show a board of 8x6 inner corners (not squares): try --board 8x6x0.117\n"
    )
    assert not out.exists()
