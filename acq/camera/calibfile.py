"""Reading and writing calib.yaml (see ARCHITECTURE.md, "the calibration file").

This module extends that format on purpose with one optional key per camera, ``std``:
one standard deviation of each calibrated parameter, from the calibrations'
covariances (:class:`CalibStd`). Every sub-key is optional; files without it stay
valid::

    std:                     # optional, written by acq calibrate
      fx: 0.21               # px, as the keys above
      fy: 0.20
      cx: 0.15
      cy: 0.14
      k: [0.001, 0.002, 0.001, 0.0005]        # as k (not for the equidistant model)
      rotation_deg: [0.05, 0.04, 0.06]        # small rotations about the LASER x, y, z
                                              # axes (R = exp([w]x) R_hat), degrees
      translation_m: [0.002, 0.003, 0.002]    # of camera_to_laser's translation, m
      time_offset_s: 0.0002                   # of time_offset_s, s

``acq calibrate fisheye --board`` writes fx, fy, cx, cy and k, ``acq calibrate
extrinsic`` rotation_deg and translation_m, ``acq calibrate time-offset``
time_offset_s; each keeps the others' part.

Every problem is reported as a :class:`CalibFileError` naming the file and the key
path, e.g. ``calib.yaml: cameras.camera.fxx: unknown key; did you mean fx?``.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, ClassVar

import yaml

from acq.camera import camera_models
from acq.camera.camera_models import CameraModel
from acq.errors import InputError
from acq.geometry.transforms import Rigid

__all__ = [
    "CalibFileError",
    "CalibStd",
    "Calibration",
    "CameraCalib",
    "UnknownCameraError",
    "dump",
    "load",
    "parse",
    "save",
]

VERSION = 1

_TOP_KEYS = {"version", "laser", "laser_to_vehicle", "cameras"}
_CAMERA_KEYS = {
    "model",
    "image_size",
    "fx",
    "fy",
    "cx",
    "cy",
    "fov_deg",
    "k",
    "camera_to_laser",
    "time_offset_s",
    "method",
    "std",
}
_RIGID_KEYS = {"rotation", "translation"}
_STD_KEYS = {"fx", "fy", "cx", "cy", "k", "rotation_deg", "translation_m", "time_offset_s"}


class CalibFileError(InputError, ValueError):
    """A calib.yaml that cannot be used; the message names the file and the key."""


class UnknownCameraError(InputError, KeyError):
    """A camera the calibration does not have, or none named where it has several (a
    KeyError, as a mapping's)."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


def _std_values(value: Any, n: int | None) -> tuple[float, ...]:
    x = tuple(float(v) for v in value)
    if n is not None and len(x) != n:
        raise ValueError(f"expected {n} standard deviations, got {len(x)}")
    if not all(math.isfinite(v) and v >= 0 for v in x):
        raise ValueError(f"standard deviations must be finite and >= 0, got {x}")
    return x


@dataclass(frozen=True)
class CalibStd:
    """One standard deviation of each calibrated parameter (None: not estimated).

    fx, fy, cx, cy px; ``k`` as the model's k (4 for kannala_brandt, 5 for pinhole);
    ``rotation_deg`` (3,) degrees of small rotations about the LASER x, y, z axes,
    ``R = exp([w]x) R_hat`` (as :class:`acq.calib.extrinsic.ExtrinsicResult`'s ``std``, not
    Euler angles: the default rig is near their gimbal lock); ``translation_m`` (3,) m;
    ``time_offset_s`` s.
    """

    INTRINSICS: ClassVar[tuple[str, ...]] = ("fx", "fy", "cx", "cy", "k")
    EXTRINSICS: ClassVar[tuple[str, ...]] = ("rotation_deg", "translation_m")

    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    k: tuple[float, ...] | None = None
    rotation_deg: tuple[float, ...] | None = None
    translation_m: tuple[float, ...] | None = None
    time_offset_s: float | None = None

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy", "time_offset_s"):
            v = getattr(self, name)
            if v is not None:
                object.__setattr__(self, name, _std_values([v], 1)[0])
        for name, n in (("k", None), ("rotation_deg", 3), ("translation_m", 3)):
            v = getattr(self, name)
            if v is not None:
                object.__setattr__(self, name, _std_values(v, n))

    def merged(self, other: CalibStd, keys: Sequence[str]) -> CalibStd:
        """This std with ``keys`` (e.g. :attr:`INTRINSICS`) taken from ``other``."""
        return replace(self, **{key: getattr(other, key) for key in keys})

    def rounded(self, digits: int = 3) -> CalibStd:
        """Every value to ``digits`` significant digits (what a writer stores)."""

        def r(x: float) -> float:
            return float(f"{x:.{digits}g}")

        out: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, tuple):
                out[f.name] = tuple(r(x) for x in v)
            elif v is not None:
                out[f.name] = r(v)
        return CalibStd(**out)

    def to_dict(self) -> dict[str, Any]:
        """The calib.yaml ``std`` entry: only the parameters that have one."""
        d: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if v is not None:
                d[f.name] = list(v) if isinstance(v, tuple) else v
        return d


@dataclass(frozen=True)
class CameraCalib:
    """One camera's intrinsics and its pose relative to the laser (paper eq. 2), with
    the standard deviations of whichever of them were calibrated (``std``)."""

    model: CameraModel
    camera_to_laser: Rigid = field(default_factory=Rigid.identity)
    time_offset_s: float = 0.0  # camera time minus laser time
    method: str = ""
    std: CalibStd = field(default_factory=CalibStd)

    def to_dict(self) -> dict[str, Any]:
        d = self.model.to_dict()
        d["camera_to_laser"] = self.camera_to_laser.to_dict()
        d["time_offset_s"] = float(self.time_offset_s)
        if self.method:
            d["method"] = self.method
        std = self.std.to_dict()
        if std:
            d["std"] = std
        return d


@dataclass(frozen=True)
class Calibration:
    """The whole calib.yaml: the reference laser, its vehicle pose, the cameras."""

    laser: str = "laser"
    cameras: dict[str, CameraCalib] = field(default_factory=dict)
    laser_to_vehicle: Rigid | None = None

    def camera(self, name: str | None = None) -> CameraCalib:
        """The named camera, or the only one when ``name`` is None."""
        if name is None:
            if len(self.cameras) != 1:
                raise UnknownCameraError(
                    f"calibration has {len(self.cameras)} cameras "
                    f"({', '.join(self.cameras) or 'none'}); name one"
                )
            return next(iter(self.cameras.values()))
        try:
            return self.cameras[name]
        except KeyError:
            raise UnknownCameraError(
                f"no camera {name!r} in the calibration (has {', '.join(self.cameras)})"
            ) from None

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"version": VERSION, "laser": self.laser}
        if self.laser_to_vehicle is not None:
            d["laser_to_vehicle"] = self.laser_to_vehicle.to_dict()
        d["cameras"] = {name: cam.to_dict() for name, cam in self.cameras.items()}
        return d


class _Reader:
    """Walks a parsed YAML tree, raising errors that name ``source`` and the key path."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, path: str, message: str) -> CalibFileError:
        where = f"{self.source}: {path}" if path else self.source
        return CalibFileError(f"{where}: {message}")

    def mapping(self, value: Any, path: str, allowed: set[str], required: set[str]) -> dict:
        if not isinstance(value, Mapping):
            raise self.fail(path, f"expected a mapping, got {type(value).__name__}")
        for key in value:
            if key not in allowed:
                hint = difflib.get_close_matches(str(key), sorted(allowed), n=1)
                extra = f"; did you mean {hint[0]}?" if hint else ""
                raise self.fail(_join(path, str(key)), f"unknown key{extra}")
        for key in sorted(required - set(value)):
            raise self.fail(_join(path, key), "missing")
        return dict(value)

    def number(self, value: Any, path: str, positive: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.fail(path, f"expected a number, got {value!r}")
        x = float(value)
        if not math.isfinite(x) or (positive and x <= 0):
            raise self.fail(path, f"expected a {'positive ' if positive else ''}finite number")
        return x

    def numbers(self, value: Any, path: str, n: int | tuple[int, ...]) -> list[float]:
        counts = (n,) if isinstance(n, int) else n
        if not isinstance(value, list | tuple) or len(value) not in counts:
            want = " or ".join(str(c) for c in counts)
            raise self.fail(path, f"expected a list of {want} numbers, got {value!r}")
        return [self.number(x, f"{path}[{i}]") for i, x in enumerate(value)]

    def rigid(self, value: Any, path: str) -> Rigid:
        d = self.mapping(value, path, _RIGID_KEYS, _RIGID_KEYS)
        rot = d["rotation"]
        if not isinstance(rot, list) or len(rot) != 3:
            raise self.fail(_join(path, "rotation"), "expected 3 rows of 3 numbers")
        rows = [self.numbers(r, f"{path}.rotation[{i}]", 3) for i, r in enumerate(rot)]
        t = self.numbers(d["translation"], _join(path, "translation"), 3)
        try:
            return Rigid(rows, t)  # type: ignore[arg-type]
        except ValueError as e:
            raise self.fail(_join(path, "rotation"), str(e)) from None

    def camera(self, value: Any, path: str) -> CameraCalib:
        d = self.mapping(value, path, _CAMERA_KEYS, {"model", "image_size", "fx", "cx", "cy"})
        model = d["model"]
        if model not in camera_models.MODELS:
            raise self.fail(
                _join(path, "model"),
                f"unknown model {model!r}; expected one of {', '.join(camera_models.MODELS)}",
            )
        size = self.numbers(d["image_size"], _join(path, "image_size"), 2)
        if any(s <= 0 or s != int(s) for s in size):
            raise self.fail(_join(path, "image_size"), "expected two positive whole numbers")
        fx = self.number(d["fx"], _join(path, "fx"), positive=True)
        fy = self.number(d.get("fy", fx), _join(path, "fy"), positive=True)
        entry: dict[str, Any] = {
            "model": model,
            "image_size": [int(s) for s in size],
            "fx": fx,
            "fy": fy,
            "cx": self.number(d["cx"], _join(path, "cx")),
            "cy": self.number(d["cy"], _join(path, "cy")),
        }
        if model in ("equidistant", "kannala_brandt"):
            entry["fov_deg"] = self.number(d.get("fov_deg", 185.0), _join(path, "fov_deg"), True)
        n_k = 5 if model == "pinhole" else 4
        if "k" in d:
            entry["k"] = self.numbers(d["k"], _join(path, "k"), n_k)
        try:
            cam = camera_models.from_dict(entry)
        except ValueError as e:
            raise self.fail(path, str(e)) from None
        extr = d.get("camera_to_laser")
        method = d.get("method", "")
        if not isinstance(method, str):
            raise self.fail(_join(path, "method"), "expected a string")
        std = CalibStd() if "std" not in d else self.std(d["std"], _join(path, "std"), model)
        return CameraCalib(
            model=cam,
            camera_to_laser=(
                Rigid.identity()
                if extr is None
                else self.rigid(extr, _join(path, "camera_to_laser"))
            ),
            time_offset_s=self.number(d.get("time_offset_s", 0.0), _join(path, "time_offset_s")),
            method=method,
            std=std,
        )

    def std(self, value: Any, path: str, model: str) -> CalibStd:
        d = self.mapping(value, path, _STD_KEYS, set())
        out: dict[str, Any] = {}
        for key in ("fx", "fy", "cx", "cy", "time_offset_s"):
            if key in d:
                out[key] = self.number(d[key], _join(path, key))
        if "k" in d:
            if model == "equidistant":
                raise self.fail(_join(path, "k"), "the equidistant model has no k")
            out["k"] = self.numbers(d["k"], _join(path, "k"), 5 if model == "pinhole" else 4)
        for key in CalibStd.EXTRINSICS:
            if key in d:
                out[key] = self.numbers(d[key], _join(path, key), 3)
        for key, v in out.items():
            if any(x < 0 for x in (v if isinstance(v, list) else [v])):
                raise self.fail(_join(path, key), "a standard deviation must be >= 0")
        return CalibStd(**out)


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def parse(data: Any, source: str = "calib.yaml") -> Calibration:
    """A :class:`Calibration` from an already-parsed YAML tree."""
    r = _Reader(source)
    d = r.mapping(data, "", _TOP_KEYS, {"version", "cameras"})
    if d["version"] != VERSION:
        raise r.fail("version", f"unsupported version {d['version']!r}; this acq reads {VERSION}")
    laser = d.get("laser", "laser")
    if not isinstance(laser, str) or not laser:
        raise r.fail("laser", "expected the scanner's name")
    cams = d["cameras"]
    if not isinstance(cams, Mapping) or not cams:
        raise r.fail("cameras", "expected a mapping of camera names to entries")
    cameras = {str(name): r.camera(entry, f"cameras.{name}") for name, entry in cams.items()}
    ltv = d.get("laser_to_vehicle")
    return Calibration(
        laser=laser,
        cameras=cameras,
        laser_to_vehicle=None if ltv is None else r.rigid(ltv, "laser_to_vehicle"),
    )


def load(path: str | Path) -> Calibration:
    """Read and validate a calib.yaml."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise CalibFileError(f"{path}: no such file") from None
    except OSError as e:
        raise CalibFileError(f"{path}: cannot read: {e.strerror}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        raise CalibFileError(f"{path}:{where} not valid YAML") from None
    return parse(data, str(path))


def dump(calib: Calibration) -> str:
    """The YAML text of a calibration."""
    return yaml.safe_dump(calib.to_dict(), sort_keys=False, default_flow_style=None)


def save(calib: Calibration, path: str | Path) -> None:
    """Write a calibration atomically (a reader never sees half a file)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(dump(calib), encoding="utf-8")
    tmp.replace(path)
