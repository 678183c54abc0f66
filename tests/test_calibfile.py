"""calib.yaml: the documented example parses, round trips, and bad files say where."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from acq import calibfile, camera_models
from acq.calibfile import CalibFileError, Calibration, CameraCalib
from acq.camera_models import Equidistant, KannalaBrandt
from acq.transforms import Rigid, rotation_from_euler

GOOD = {
    "version": 1,
    "laser": "laser",
    "cameras": {
        "camera": {
            "model": "equidistant",
            "image_size": [780, 582],
            "fx": 169.3,
            "fy": 169.3,
            "cx": 390.2,
            "cy": 291.1,
            "fov_deg": 185.0,
            "camera_to_laser": {
                "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
                "translation": [0.1, 0.0, -0.2],
            },
        }
    },
}


def write(tmp_path: Path, data: object) -> Path:
    p = tmp_path / "calib.yaml"
    p.write_text(yaml.safe_dump(data), encoding="utf-8")
    return p


def test_architecture_example_parses(shared_dir: Path) -> None:
    text = (shared_dir / "ARCHITECTURE.md").read_text(encoding="utf-8")
    block = re.search(r"```yaml\n(# calib\.yaml.*?)```", text, re.S)
    assert block, "ARCHITECTURE.md has no calib.yaml example"
    calib = calibfile.parse(yaml.safe_load(block.group(1)), "ARCHITECTURE.md")
    cam = calib.camera("camera")
    assert isinstance(cam.model, Equidistant)
    assert cam.model.f == pytest.approx(169.3)
    assert calib.laser_to_vehicle is not None


def test_round_trip(tmp_path: Path) -> None:
    calib = Calibration(
        laser="laser",
        cameras={
            "left": CameraCalib(
                KannalaBrandt(780, 582, 169.0, 169.4, 390.2, 291.1, (0.007, -0.001, 0.0, 0.0)),
                Rigid(rotation_from_euler(0.01, -1.5, 0.3), [0.3, -0.1, 0.2]),
                time_offset_s=0.004,
                method="board",
            ),
            "right": CameraCalib(Equidistant.from_f(170.0, 389.0, 290.0, 780, 582)),
        },
        laser_to_vehicle=Rigid(rotation_from_euler(0, 0.5, 0), [-0.5, 0, 2.2]),
    )
    path = tmp_path / "calib.yaml"
    calibfile.save(calib, path)
    again = calibfile.load(path)
    assert again.cameras["left"].model == calib.cameras["left"].model
    assert again.cameras["right"].model == calib.cameras["right"].model
    np.testing.assert_allclose(
        again.cameras["left"].camera_to_laser.matrix(),
        calib.cameras["left"].camera_to_laser.matrix(),
        atol=1e-15,
    )
    assert again.cameras["left"].time_offset_s == 0.004
    assert camera_models.load(path, camera="right") == calib.cameras["right"].model
    with pytest.raises(KeyError, match="name one"):
        camera_models.load(path)


def test_unknown_key_names_path_and_suggests(tmp_path: Path) -> None:
    data = yaml.safe_load(yaml.safe_dump(GOOD))
    data["cameras"]["camera"]["fxx"] = 1.0
    with pytest.raises(CalibFileError, match=r"calib\.yaml: cameras\.camera\.fxx: unknown key; "
                       r"did you mean fx\?"):  # fmt: skip
        calibfile.load(write(tmp_path, data))


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d["cameras"]["camera"].pop("cx"), r"cameras\.camera\.cx: missing"),
        (lambda d: d["cameras"]["camera"].update(fx="big"), r"cameras\.camera\.fx: expected"),
        (lambda d: d["cameras"]["camera"].update(fy=170.0), r"cameras\.camera: .*square pixels"),
        (lambda d: d["cameras"]["camera"].update(model="ocam"), r"cameras\.camera\.model: unknown"),
        (lambda d: d["cameras"]["camera"].update(k=[0.1]), r"cameras\.camera\.k: expected a list"),
        (
            lambda d: d["cameras"]["camera"]["camera_to_laser"].update(
                rotation=[[1, 0, 0], [0, 1, 0], [0, 0, -1]]
            ),
            r"cameras\.camera\.camera_to_laser\.rotation: .*proper rotation",
        ),
        (lambda d: d.update(version=2), r"version: unsupported version 2"),
        (lambda d: d.update(cameras={}), r"cameras: expected a mapping"),
    ],
)
def test_bad_values_are_reported_with_their_path(
    tmp_path: Path, edit: object, message: str
) -> None:
    data = yaml.safe_load(yaml.safe_dump(GOOD))
    edit(data)  # type: ignore[operator]
    with pytest.raises(CalibFileError, match=message):
        calibfile.load(write(tmp_path, data))


def test_missing_file_and_bad_yaml(tmp_path: Path) -> None:
    with pytest.raises(CalibFileError, match="no such file"):
        calibfile.load(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("version: 1\ncameras: [unclosed\n", encoding="utf-8")
    with pytest.raises(CalibFileError, match=r"bad\.yaml: line \d+, column \d+ not valid YAML"):
        calibfile.load(bad)
