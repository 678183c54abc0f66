"""calib.yaml: the documented example parses, round trips, and bad files say where."""

from __future__ import annotations

import copy
import re
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from acq import camera_models  # the API name of ARCHITECTURE.md
from acq.camera import calibfile
from acq.camera.calibfile import CalibFileError, Calibration, CalibStd, CameraCalib
from acq.camera.camera_models import Equidistant, KannalaBrandt
from acq.geometry.rotations import rotation_from_euler
from acq.geometry.transforms import Rigid

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
        (lambda d: d["cameras"]["camera"].pop("cx"), r"cameras\.camera\.cx: required key missing"),
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
        (
            lambda d: d.update(version=True),
            r"version: expected 1 \(the version this acq reads\), got True",
        ),
        (lambda d: d.update(cameras={}), r"cameras: expected a mapping"),
        (
            lambda d: d.update(camera={}),
            r"^\S*calib\.yaml: camera: unknown key; did you mean cameras\?",
        ),
        (lambda d: d.update(laser=""), r"laser: expected the scanner's name, got ''"),
        (
            lambda d: d["cameras"]["camera"].update(model="equidistnat"),
            r"model: unknown model 'equidistnat'; did you mean equidistant\?$",
        ),
        (
            lambda d: d["cameras"]["camera"].update(fx=-1),
            r"cameras\.camera\.fx: must be >= 1, got -1",
        ),
        (
            lambda d: d["cameras"]["camera"].update(image_size=[780.5, 582]),
            r"image_size: expected two whole numbers 1..65535",
        ),
        (
            lambda d: d["cameras"]["camera"]["camera_to_laser"].update(rotation=[[1, 0, 0]]),
            r"camera_to_laser\.rotation: expected 3 rows of 3 numbers",
        ),
        (
            lambda d: d["cameras"]["camera"]["camera_to_laser"].update(translation=[0, 0]),
            r"camera_to_laser\.translation: expected a list of 3 numbers, got 2",
        ),
        (
            lambda d: d["cameras"]["camera"].update(cx=10**400),
            r"cameras\.camera\.cx: expected a number, got 1000",
        ),
        (
            lambda d: d["cameras"]["camera"].update(time_offset_s="1e12"),  # YAML 1.1: text
            r"time_offset_s: expected a number, got '1e12' \(text to YAML; write "
            r"1000000000000\.0 for the number\)$",
        ),
        (
            lambda d: d["cameras"]["camera"].update(fx="1e308"),
            r"fx: expected a number, got '1e308' \(text to YAML; write 1\.0e\+308 for the",
        ),
    ],
)
def test_bad_values_are_reported_with_their_path(
    tmp_path: Path, edit: object, message: str
) -> None:
    data = yaml.safe_load(yaml.safe_dump(GOOD))
    edit(data)  # type: ignore[operator]
    with pytest.raises(CalibFileError, match=message):
        calibfile.load(write(tmp_path, data))


def test_whole_floats_and_null_optional_sections_read(tmp_path: Path) -> None:
    data = yaml.safe_load(yaml.safe_dump(GOOD))
    cam = data["cameras"]["camera"]
    cam.update(image_size=[780.0, 582.0], std=None, fy=None)
    data["laser_to_vehicle"] = None
    calib = calibfile.load(write(tmp_path, data))
    model = calib.camera().model
    assert (model.width, model.height) == (780, 582) and model.fy == model.fx
    assert calib.laser_to_vehicle is None
    with pytest.raises(CalibFileError, match=r"calib\.yaml: expected a mapping with version"):
        calibfile.parse([GOOD])


def test_missing_file_and_bad_yaml(tmp_path: Path) -> None:
    with pytest.raises(CalibFileError, match="no such file"):
        calibfile.load(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("version: 1\ncameras: [unclosed\n", encoding="utf-8")
    with pytest.raises(CalibFileError, match=r"bad\.yaml:3:1: invalid YAML: expected ',' or ']'"):
        calibfile.load(bad)
    bad.write_text("version: 1\nversion: 1\n", encoding="utf-8")
    with pytest.raises(CalibFileError, match=r"bad\.yaml:2:1: invalid YAML: duplicate key version"):
        calibfile.load(bad)
    bad.write_bytes(b"version: 1\nlaser: \xff\n")
    with pytest.raises(CalibFileError, match=r"bad\.yaml: not UTF-8 text \(byte 18\)"):
        calibfile.load(bad)


@pytest.mark.parametrize("absent", [None, "removed"])
def test_a_camera_without_its_pose_is_refused_unless_read_for_intrinsics(
    tmp_path: Path, absent: str | None
) -> None:
    data = yaml.safe_load(yaml.safe_dump(GOOD))
    data["cameras"]["left"] = copy.deepcopy(data["cameras"]["camera"])
    if absent is None:
        data["cameras"]["left"]["camera_to_laser"] = None
    else:
        del data["cameras"]["left"]["camera_to_laser"]
    path = write(tmp_path, data)
    where = re.escape(f"{path}: cameras.left.camera_to_laser: required key missing")
    with pytest.raises(CalibFileError, match="^" + where):
        calibfile.load(path)
    calib = calibfile.load(path, intrinsics_only=True)
    left = calib.camera("left")
    assert left.extrinsics is None and calib.camera("camera").extrinsics is not None
    assert camera_models.load(path, camera="left") == left.model
    with pytest.raises(CalibFileError, match="^" + where):
        left.camera_to_laser  # noqa: B018 (the access raises)
    # written back without a pose, not with the identity
    again = yaml.safe_load(calibfile.dump(calib))
    assert "camera_to_laser" not in again["cameras"]["left"]
    assert calibfile.parse(again, intrinsics_only=True).to_dict() == calib.to_dict()


_RANGE_CASES = [
    ("fx", 1e308, r"cameras\.camera\.fx: must be <= 1e\+06, got 1e\+308"),
    ("fx", 1e-300, r"cameras\.camera\.fx: must be >= 1, got 1e-300"),
    ("cx", 1e300, r"cameras\.camera\.cx: the principal point must be within one image size "
     r"of the image \(-780\.\.1560 px\), got 1e\+300"),
    ("cy", -1e9, r"cameras\.camera\.cy: the principal point .*\(-582\.\.1164 px\)"),
    ("image_size", [10**9, 582], r"cameras\.camera\.image_size: expected two whole numbers"),
    ("fov_deg", 360.0, r"cameras\.camera\.fov_deg: must be < 360, got 360\.0"),
    ("time_offset_s", 1e12,
     r"cameras\.camera\.time_offset_s: must be <= 3600, got 1000000000000\.0"),
    ("time_offset_s", -3600.5, r"cameras\.camera\.time_offset_s: must be >= -3600"),
    ("translation", [1e308, 0, 0],
     r"cameras\.camera\.camera_to_laser\.translation\[0\]: must be <= 100, got 1e\+308"),
    ("rotation", [[1e200, 0, 0], [0, 1, 0], [0, 0, 1]],
     r"cameras\.camera\.camera_to_laser\.rotation\[0\]\[0\]: not a rotation"),
    ("k", [1e300, 0, 0, 0], r"cameras\.camera\.k\[0\]: must be <= 1000, got 1e\+300"),
    ("std", {"fx": 1e308}, r"cameras\.camera\.std\.fx: must be <= 1e\+06, got 1e\+308"),
    ("std", {"rotation_deg": [0.1, 400.0, 0.1]},
     r"cameras\.camera\.std\.rotation_deg\[1\]: must be <= 180, got 400\.0"),
    ("laser_to_vehicle", {"rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
                          "translation": [0, 0, 1e6]},
     r"^\S*calib\.yaml: laser_to_vehicle\.translation\[2\]: must be <= 100"),
]  # fmt: skip


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize(("key", "value", "message"), _RANGE_CASES)
def test_numbers_out_of_range_are_refused_with_their_key(
    tmp_path: Path, key: str, value: object, message: str
) -> None:
    data = yaml.safe_load(yaml.safe_dump(GOOD))
    cam = data["cameras"]["camera"]
    if key == "k":
        cam["model"] = "kannala_brandt"
    if key in ("translation", "rotation"):
        cam["camera_to_laser"][key] = value
    elif key == "laser_to_vehicle":
        data[key] = value
    else:
        cam[key] = value
    with pytest.raises(CalibFileError, match=message):
        calibfile.load(write(tmp_path, data))


# --- std: the calibrations' standard deviations -------------------------------------------

STD = {
    "fx": 0.21,
    "fy": 0.2,
    "cx": 0.15,
    "cy": 0.14,
    "k": [0.001, 0.002, 0.001, 0.0005],
    "rotation_deg": [0.05, 0.04, 0.06],
    "translation_m": [0.002, 0.003, 0.002],
    "time_offset_s": 0.0002,
}


def test_std_round_trips_and_is_written_only_when_present(tmp_path: Path) -> None:
    full = CalibStd(**{k: tuple(v) if isinstance(v, list) else v for k, v in STD.items()})
    calib = Calibration(
        cameras={
            "left": CameraCalib(
                KannalaBrandt(780, 582, 169.0, 169.4, 390.2, 291.1, (0.007, -0.001, 0.0, 0.0)),
                Rigid(rotation_from_euler(0.01, -1.5, 0.3), [0.3, -0.1, 0.2]),
                method="board",
                std=full,
            ),
            "right": CameraCalib(
                Equidistant.from_f(170.0, 389.0, 290.0, 780, 582),
                std=CalibStd(rotation_deg=(0.1, 0.2, 0.3)),
            ),
            "plain": CameraCalib(Equidistant.from_f(170.0, 389.0, 290.0, 780, 582)),
        }
    )
    path = tmp_path / "calib.yaml"
    calibfile.save(calib, path)
    again = calibfile.load(path)
    for name in calib.cameras:
        assert again.cameras[name].std == calib.cameras[name].std, name
    assert again.to_dict() == calib.to_dict()
    assert calibfile.parse(yaml.safe_load(calibfile.dump(again))).to_dict() == calib.to_dict()
    raw = yaml.safe_load(path.read_text())["cameras"]
    assert raw["left"]["std"] == STD
    assert raw["right"]["std"] == {"rotation_deg": [0.1, 0.2, 0.3]}
    assert "std" not in raw["plain"]
    # files without std (every existing one) read as an empty std
    assert calibfile.parse(GOOD).camera().std == CalibStd()
    assert calibfile.parse(GOOD).camera().std.to_dict() == {}


def test_calib_std_normalises_merges_and_rounds() -> None:
    s = CalibStd(fx=np.float64(0.123456), k=np.array([1e-3, 2e-3, 0.0, 0.0]))
    assert s.k == (1e-3, 2e-3, 0.0, 0.0) and type(s.fx) is float
    r = s.rounded(2)
    assert r.fx == 0.12 and r.k == s.k and r.cx is None
    e = CalibStd(rotation_deg=(0.1, 0.2, 0.3), translation_m=(1e-3, 2e-3, 3e-3))
    both = s.merged(e, CalibStd.EXTRINSICS)
    assert both.fx == s.fx and both.rotation_deg == e.rotation_deg
    assert both.merged(CalibStd(), CalibStd.INTRINSICS) == CalibStd(
        rotation_deg=e.rotation_deg, translation_m=e.translation_m
    )
    with pytest.raises(ValueError, match=">= 0"):
        CalibStd(cx=-0.1)
    with pytest.raises(ValueError, match="expected 3"):
        CalibStd(translation_m=(0.1, 0.2))


def _with_std(std: object) -> dict:
    data = yaml.safe_load(yaml.safe_dump(GOOD))
    data["cameras"]["camera"]["std"] = std
    return data


@pytest.mark.parametrize(
    ("std", "message"),
    [
        ({"fxx": 0.1}, r"fxx: unknown key; did you mean fx\?"),
        ({"rotation": [0.1] * 3}, r"rotation: unknown key; did you mean rotation_deg\?"),
        ({"translation": [0.1] * 3}, r"translation: unknown key; did you mean translation_m\?"),
        ({"fx": -0.1}, r"fx: a standard deviation must be >= 0"),
        ({"time_offset_s": -0.001}, r"time_offset_s: a standard deviation must be >= 0"),
        ({"time_offset": 0.001}, r"time_offset: unknown key; did you mean time_offset_s\?"),
        ({"cx": "big"}, r"cx: expected a number"),
        ({"translation_m": [0.1, 0.2]}, r"translation_m: expected a list of 3 numbers"),
        ({"rotation_deg": [0.1, float("nan"), 0.1]}, r"rotation_deg\[1\]: expected a finite"),
        ({"rotation_deg": [0.1, -0.2, 0.1]}, r"rotation_deg: a standard deviation must be >= 0"),
        ({"k": [0.1, 0.0, 0.0, 0.0]}, r"k: the equidistant model has no k"),
        ([0.1], r": expected a mapping, got a list"),
    ],
)
def test_bad_std_is_reported_with_its_path(tmp_path: Path, std: object, message: str) -> None:
    where = r"calib\.yaml: cameras\.camera\.std" + ("" if isinstance(std, list) else r"\.")
    with pytest.raises(CalibFileError, match=where + message):
        calibfile.load(write(tmp_path, _with_std(std)))


def test_std_k_has_the_models_length(tmp_path: Path) -> None:
    data = _with_std({"k": [0.1, 0.0, 0.0, 0.0, 0.0]})
    cam = data["cameras"]["camera"]
    cam.update(model="kannala_brandt", k=[0.0] * 4)
    with pytest.raises(CalibFileError, match=r"std\.k: expected a list of 4 numbers"):
        calibfile.load(write(tmp_path, data))
    cam.update(model="pinhole", k=[0.0] * 5)
    del cam["fov_deg"]
    assert calibfile.load(write(tmp_path, data)).camera().std.k == (0.1, 0.0, 0.0, 0.0, 0.0)


# --- fuzzing: any YAML mapping is a Calibration or one CalibFileError ---------------------

_KEYS = sorted(
    {"version", "laser", "laser_to_vehicle", "cameras", "camera", "rotation", "translation"}
    | set(GOOD["cameras"]["camera"])  # type: ignore[index]
    | {"k", "time_offset_s", "method", "std", *STD}
)
_SCALARS = (
    st.none()
    | st.booleans()
    | st.integers()
    | st.sampled_from([0, 1, -1, 2, 10**400, 1e308, 0.5])
    | st.floats()
    | st.text(max_size=6)
    | st.sampled_from([*_KEYS, "equidistant", "kannala_brandt", "pinhole"])
)
_NAMES = st.sampled_from(_KEYS) | st.text(max_size=6) | st.integers(-3, 3)
_VALUES = st.recursive(
    _SCALARS,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(_NAMES, inner, max_size=4),
    max_leaves=10,
)
_FULL = {
    **GOOD,
    "laser_to_vehicle": {"rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "translation": [0, 0, 2]},
    "cameras": {
        **GOOD["cameras"],  # type: ignore[dict-item]
        "kb": {
            "model": "kannala_brandt",
            "image_size": [780, 582],
            "fx": 169.0,
            "cx": 390.0,
            "cy": 291.0,
            "k": [0.0] * 4,
            "camera_to_laser": {
                "rotation": [[0, 0, 1], [-1, 0, 0], [0, -1, 0]],
                "translation": [0.2, -0.1, 0.3],
            },
            "time_offset_s": 0.01,
            "method": "board",
            "std": STD,
        },
    },
}


def _nodes(tree: Any, at: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """The path of every node below ``tree`` (keys and indices)."""
    items = (
        tree.items()
        if isinstance(tree, dict)
        else enumerate(tree)
        if isinstance(tree, list)
        else ()
    )
    out = []
    for key, value in items:
        out.append((*at, key))
        out += _nodes(value, (*at, key))
    return out


@st.composite
def _edited(draw: st.DrawFn) -> dict[str, Any]:
    """A good file with one to three nodes replaced, removed or added."""
    data: dict[str, Any] = copy.deepcopy(_FULL)
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(_nodes(data)))
        parent: Any = data
        for key in path[:-1]:
            parent = parent[key]
        edit = draw(st.sampled_from(["replace", "remove", "add"]))
        if edit == "replace":
            parent[path[-1]] = draw(_VALUES)
        elif edit == "remove" and isinstance(parent, dict):
            del parent[path[-1]]
        elif isinstance(parent, dict):
            parent[draw(_NAMES)] = draw(_VALUES)
    return data


def _parses_or_says_where(data: Any) -> None:
    try:
        calib = calibfile.parse(data, "f.yaml")
    except CalibFileError as e:
        text = str(e)
        assert text.startswith("f.yaml: ") and "\n" not in text, text
        return
    # what it read, it writes and reads back the same
    again = calibfile.parse(yaml.safe_load(calibfile.dump(calib)))
    assert again.to_dict() == calib.to_dict()


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_edited())
def test_fuzz_edited_files_parse_or_say_where(data: dict[str, Any]) -> None:
    _parses_or_says_where(data)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.dictionaries(_NAMES, _VALUES, max_size=5))
def test_fuzz_any_mapping_parses_or_says_where(data: dict[Any, Any]) -> None:
    _parses_or_says_where(data)


# --- fuzzing the numbers: what loads projects without a numpy warning --------------------


def _at(tree: Any, path: tuple[Any, ...]) -> Any:
    for key in path:
        tree = tree[key]
    return tree


_NUMERIC_PATHS = [
    path
    for path in _nodes(_FULL)
    if isinstance(_at(_FULL, path), int | float) and path[-1] != "version"
]
_NUMBERS = (
    st.floats()
    | st.integers()
    | st.sampled_from([1e308, -1e308, -0.0, 1e-300, 10**400, 65535, 65536, 3600.5, 1e6, 1001])
    | st.text(max_size=3)
)
_POINTS = np.array([[0.1, 0.2, 1.0], [1.0, 0.0, 0.01], [0.0, 0.0, -1.0], [3.0, -2.0, 5.0]])


def _key_text(path: tuple[Any, ...]) -> str:
    """A node's path as the messages write it: ``cameras.kb.k[2]``."""
    return "".join(f"[{k}]" if isinstance(k, int) else f".{k}" for k in path).lstrip(".")


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.sampled_from(_NUMERIC_PATHS), _NUMBERS), min_size=1, max_size=3))
def test_fuzz_numbers_load_and_project_quietly_or_name_the_key(
    edits: list[tuple[tuple[Any, ...], Any]],
) -> None:
    from acq.camera import projection

    data: dict[str, Any] = copy.deepcopy(_FULL)
    for path, value in edits:
        parent: Any = data
        for key in path[:-1]:
            parent = parent[key]
        parent[path[-1]] = value
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            calib = calibfile.parse(data, "f.yaml")
        except CalibFileError as e:
            text = str(e)
            assert text.startswith("f.yaml: ") and "\n" not in text, text
            where = text.removeprefix("f.yaml: ").split(": ", 1)[0]
            edited = [_key_text(path) for path, _ in edits]
            # the key itself, or the camera or section it belongs to
            assert any(k.startswith(where) or where.startswith(k.rsplit(".", 1)[0])
                       for k in edited), (where, edited)  # fmt: skip
            return
        for cam in calib.cameras.values():
            uv, valid = cam.model.project(_POINTS)
            assert uv.shape == (4, 2) and valid.shape == (4,)
            uv32, _ = projection.project(_POINTS, cam.model, cam.camera_to_laser)
            assert uv32.shape == (4, 2)
            assert abs(round(cam.time_offset_s * 1e9)) <= 3600 * 10**9
        assert calibfile.parse(yaml.safe_load(calibfile.dump(calib))).to_dict() == calib.to_dict()


def test_merged_replaces_the_cameras_named_and_keeps_the_rest() -> None:
    model = KannalaBrandt(width=780, height=582, fx=169.0, fy=169.0, cx=390.0, cy=291.0)
    a, b = Rigid(np.eye(3), np.ones(3)), Rigid(np.eye(3), np.zeros(3))
    ltv = Rigid(np.eye(3), np.array([0.0, 0.0, 2.0]))
    old = Calibration(
        cameras={"left": CameraCalib(model, a, 0.01), "rear": CameraCalib(model, a)},
        laser_to_vehicle=ltv,
    )
    new = Calibration(cameras={"left": CameraCalib(model), "right": CameraCalib(model, b),
                               "rear": CameraCalib(model, b)})  # fmt: skip
    out = calibfile.merged(old, new, ["right"], "calib.yaml")
    assert list(out.cameras) == ["left", "rear", "right"]
    assert out.cameras["left"] is old.cameras["left"]  # not named: kept as it was
    assert out.cameras["rear"] is old.cameras["rear"]
    assert out.cameras["right"] is new.cameras["right"]
    assert out.laser_to_vehicle is ltv
    with pytest.raises(CalibFileError, match=r"^calib.yaml: .* laser 'laser', .* 'scanner2'"):
        calibfile.merged(old, Calibration(laser="scanner2"), [], "calib.yaml")


def test_method_with_sets_one_part_and_keeps_the_others() -> None:
    """A calibration step says how it got its part of a camera's entry beside the
    others' (acq calibrate time-offset on a calibration of another origin)."""
    m = calibfile.method_with("simulator truth", "time_offset_s", "estimated from a.mcap")
    assert m == "simulator truth; time_offset_s: estimated from a.mcap"
    again = calibfile.method_with(m, "time_offset_s", "estimated from b.mcap")
    assert again == "simulator truth; time_offset_s: estimated from b.mcap"
    assert calibfile.method_with("", "time_offset_s", "x") == "time_offset_s: x"
