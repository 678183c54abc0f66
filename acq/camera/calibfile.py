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

And one optional line per camera, ``note``: what its intrinsics rest on that no figure
shows (``acq calibrate fisheye`` from the circle alone: the stated aperture and an
equidistant lens, and the range of f an aperture 5 degrees off gives); kept by the
other calibrations, replaced when the intrinsics are.

Every number is checked against the bounds below (finite, focal lengths and image sizes
positive and bounded, the principal point near the image, distortion coefficients,
translations and the time offset bounded), so what loads projects without overflow.
A camera without ``camera_to_laser`` is an error unless the file is read for its
intrinsics only (``load(..., intrinsics_only=True)``, as ``acq calibrate fisheye`` and
``acq calibrate extrinsic --intrinsics`` do); such a camera keeps no pose
(:attr:`CameraCalib.extrinsics` None) and is written back without one.

Every problem is reported as a :class:`CalibFileError` naming the file and the key
path, e.g. ``calib.yaml: cameras.camera.fxx: unknown key; did you mean fx?``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Annotated, Any, ClassVar

import yaml
from pydantic import BaseModel, Field, ValidationError, field_validator, model_validator

from acq import yamlcheck
from acq.atomic_write import atomic
from acq.camera import camera_models
from acq.camera.camera_models import CameraModel
from acq.errors import InputError, InputValueError
from acq.geometry.transforms import Rigid
from acq.yamlcheck import did_you_mean, fail, show

__all__ = [
    "CalibFileError",
    "CalibStd",
    "Calibration",
    "CameraCalib",
    "UnknownCameraError",
    "dump",
    "load",
    "merged",
    "method_with",
    "parse",
    "save",
]

VERSION = 1

MAX_SIDE_PX = 65535
"""The largest image width or height, px (JPEG's limit)."""
FOCAL_PX = (1.0, 1e6)
"""The range of fx and fy, px (per radian for the fisheye models)."""
MAX_K = 1e3
"""The largest magnitude of a distortion coefficient."""
MAX_TRANSLATION_M = 100.0
"""The largest magnitude of a translation's component, m (a rig's sensors are nearer)."""
MAX_TIME_OFFSET_S = 3600.0
"""The largest magnitude of ``time_offset_s``, s."""


class CalibFileError(InputValueError):
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
    the standard deviations of whichever of them were calibrated (``std``).

    ``extrinsics`` is ``camera_to_laser`` as known: None for a camera read for its
    intrinsics only from a file without one, whose :attr:`camera_to_laser` then raises
    (``source`` and ``name`` say where it was read, for that message).
    """

    model: CameraModel
    extrinsics: Rigid | None = field(default_factory=Rigid.identity)
    time_offset_s: float = 0.0  # camera time minus laser time
    method: str = ""
    std: CalibStd = field(default_factory=CalibStd)
    note: str = ""  # what the intrinsics rest on, unchecked (module docstring)
    source: str = field(default="", compare=False, repr=False)
    name: str = field(default="", compare=False, repr=False)

    @property
    def camera_to_laser(self) -> Rigid:
        """``P_laser = R @ P_camera + t``; CalibFileError when the camera has none."""
        if self.extrinsics is None:
            raise CalibFileError(
                yamlcheck.line(
                    self.source or "calib.yaml",
                    f"cameras.{self.name or 'camera'}.camera_to_laser",
                    _NO_EXTRINSICS,
                )
            )
        return self.extrinsics

    def to_dict(self) -> dict[str, Any]:
        d = self.model.to_dict()
        if self.extrinsics is not None:
            d["camera_to_laser"] = self.extrinsics.to_dict()
        d["time_offset_s"] = float(self.time_offset_s)
        if self.method:
            d["method"] = self.method
        std = self.std.to_dict()
        if std:
            d["std"] = std
        if self.note:
            d["note"] = self.note
        return d


@dataclass(frozen=True)
class Calibration:
    """The whole calib.yaml: the reference laser, its vehicle pose, the cameras."""

    laser: str = "laser"
    cameras: dict[str, CameraCalib] = field(default_factory=dict)
    laser_to_vehicle: Rigid | None = None
    source: str = field(default="", compare=False)  # the file it was read from, or ""

    @property
    def label(self) -> str:
        """How messages name it: its file, or "the calibration"."""
        return self.source or "the calibration"

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


_NO_EXTRINSICS = (
    "required key missing (the camera's pose relative to the laser, which acq calibrate "
    "extrinsic writes)"
)


class _Model(BaseModel):
    model_config = yamlcheck.STRICT


_K = Annotated[float, Field(ge=-MAX_K, le=MAX_K)]
_Metres = Annotated[float, Field(ge=-MAX_TRANSLATION_M, le=MAX_TRANSLATION_M)]
_Focal = Annotated[float, Field(ge=FOCAL_PX[0], le=FOCAL_PX[1])]
_Offset = Annotated[float, Field(ge=-MAX_TIME_OFFSET_S, le=MAX_TIME_OFFSET_S)]


def _count(v: list[float], n: int, *subpath: str) -> list[float]:
    """``v`` if it holds ``n`` numbers (the error at ``subpath`` below the value checked)."""
    if len(v) != n:
        raise fail(f"expected a list of {n} numbers, got {len(v)}", *subpath)
    return v


def _not_negative(v: Any) -> Any:
    if v is not None and any(x < 0 for x in (v if isinstance(v, list) else [v])):
        raise fail("a standard deviation must be >= 0")
    return v


class _Rigid(_Model):
    """``P_to = rotation @ P_from + translation``: a rotation matrix, metres."""

    rotation: list[list[float]]
    translation: list[_Metres]

    @field_validator("rotation")
    @classmethod
    def _rows(cls, v: list[list[float]]) -> list[list[float]]:
        if len(v) != 3 or any(len(row) != 3 for row in v):
            raise fail("expected 3 rows of 3 numbers")
        for i, row in enumerate(v):
            for j, x in enumerate(row):
                if abs(x) > 1.0 + 1e-6:  # before R R^T, which would overflow
                    raise fail(f"not a rotation: an entry of {show(x)}", i, j)
        return v

    _three = field_validator("translation")(lambda v: _count(v, 3))

    @model_validator(mode="after")
    def _proper(self) -> _Rigid:
        try:
            self.rigid()
        except ValueError as e:
            raise fail(str(e), "rotation") from None
        return self

    def rigid(self) -> Rigid:
        return Rigid(self.rotation, self.translation)  # type: ignore[arg-type]


_Px = Annotated[float, Field(le=FOCAL_PX[1])]


class _Std(_Model):
    """A camera's ``std`` (:class:`CalibStd`), each bounded as its parameter; ``k``'s
    length is checked by the camera."""

    fx: _Px | None = None
    fy: _Px | None = None
    cx: _Px | None = None
    cy: _Px | None = None
    k: list[Annotated[float, Field(le=MAX_K)]] | None = None
    rotation_deg: list[Annotated[float, Field(le=180.0)]] | None = None
    translation_m: list[Annotated[float, Field(le=MAX_TRANSLATION_M)]] | None = None
    time_offset_s: Annotated[float, Field(le=MAX_TIME_OFFSET_S)] | None = None

    _three = field_validator("rotation_deg", "translation_m")(
        lambda v: v if v is None else _count(v, 3)
    )
    _sign = field_validator("*")(_not_negative)


class _Camera(_Model):
    """One entry of ``cameras`` (ARCHITECTURE.md, "the calibration file")."""

    model: str
    image_size: list[float]  # width, height, px (whole numbers, 780.0 too)
    fx: _Focal
    fy: _Focal | None = None  # default fx
    cx: float  # within one image size of the image (checked below)
    cy: float
    fov_deg: float | None = Field(default=None, gt=0, lt=360)  # fisheye models; default 185
    k: list[_K] | None = None
    camera_to_laser: _Rigid | None = None  # None: intrinsics only
    time_offset_s: _Offset = 0.0
    method: str = ""
    std: _Std | None = None
    note: str = ""

    @field_validator("model")
    @classmethod
    def _model(cls, v: str) -> str:
        if v not in camera_models.MODELS:
            hint = did_you_mean(v, list(camera_models.MODELS))
            raise fail(
                f"unknown model {v!r}{hint}"
                if hint
                else f"unknown model {v!r}; expected one of {', '.join(camera_models.MODELS)}"
            )
        return v

    @field_validator("image_size")
    @classmethod
    def _size(cls, v: list[float]) -> list[float]:
        _count(v, 2)
        if any(not 0 < s <= MAX_SIDE_PX or s != int(s) for s in v):
            raise fail(f"expected two whole numbers 1..{MAX_SIDE_PX}, got {v}")
        return v

    @model_validator(mode="after")
    def _consistent(self) -> _Camera:
        for key, c, side in (
            ("cx", self.cx, self.image_size[0]),
            ("cy", self.cy, self.image_size[1]),
        ):
            if not -side <= c <= 2 * side:
                raise fail(
                    f"the principal point must be within one image size of the image "
                    f"({-side:g}..{2 * side:g} px), got {show(c)}",
                    key,
                )
        n_k = 5 if self.model == "pinhole" else 4
        if self.k is not None:
            _count(self.k, n_k, "k")
        if self.std is not None and self.std.k is not None:
            if self.model == "equidistant":
                raise fail("the equidistant model has no k", "std", "k")
            _count(self.std.k, n_k, "std", "k")
        try:
            self.camera_model()
        except ValueError as e:
            raise fail(str(e)) from None
        return self

    def camera_model(self) -> CameraModel:
        entry: dict[str, Any] = {
            "model": self.model,
            "image_size": [int(s) for s in self.image_size],
            "fx": self.fx,
            "fy": self.fx if self.fy is None else self.fy,
            "cx": self.cx,
            "cy": self.cy,
        }
        if self.model in ("equidistant", "kannala_brandt"):
            entry["fov_deg"] = 185.0 if self.fov_deg is None else self.fov_deg
        if self.k is not None:
            entry["k"] = self.k
        return camera_models.from_dict(entry)

    def calib(self, source: str, name: str) -> CameraCalib:
        std = self.std.model_dump(exclude_none=True) if self.std is not None else {}
        return CameraCalib(
            model=self.camera_model(),
            extrinsics=None if self.camera_to_laser is None else self.camera_to_laser.rigid(),
            time_offset_s=self.time_offset_s,
            method=self.method,
            std=CalibStd(**std),
            note=self.note,
            source=source,
            name=name,
        )


class _File(_Model):
    """The whole calib.yaml."""

    version: int
    laser: str = "laser"
    laser_to_vehicle: _Rigid | None = None
    cameras: dict[str, _Camera]

    @field_validator("version", mode="plain")
    @classmethod
    def _version(cls, v: Any) -> int:
        if type(v) is not int:
            raise fail(f"expected {VERSION} (the version this acq reads), got {show(v)}")
        if v != VERSION:
            raise fail(f"unsupported version {v}; this acq reads {VERSION}")
        return v

    @field_validator("laser", mode="before")
    @classmethod
    def _laser(cls, v: Any) -> Any:
        if not isinstance(v, str) or not v:
            raise fail(f"expected the scanner's name, got {show(v)}")
        return v

    @field_validator("cameras", mode="before")
    @classmethod
    def _cameras(cls, v: Any) -> Any:
        if not isinstance(v, Mapping) or not v:
            raise fail(f"expected a mapping of camera names to entries, got {show(v)}")
        return {str(name): entry for name, entry in v.items()}


def parse(data: Any, source: str = "calib.yaml", *, intrinsics_only: bool = False) -> Calibration:
    """A :class:`Calibration` from an already-parsed YAML tree; ``source`` names the file
    in error messages. A camera without ``camera_to_laser`` is an error unless
    ``intrinsics_only``."""
    if not isinstance(data, Mapping):
        raise CalibFileError(
            yamlcheck.line(
                source, "", f"expected a mapping with version: 1 and cameras, got {show(data)}"
            )
        )
    try:
        f = _File.model_validate(dict(data))
    except ValidationError as e:
        raise CalibFileError(yamlcheck.message(e, source, _File)) from None
    if not intrinsics_only:
        for name, cam in f.cameras.items():
            if cam.camera_to_laser is None:
                where = f"cameras.{name}.camera_to_laser"
                raise CalibFileError(yamlcheck.line(source, where, _NO_EXTRINSICS))
    return Calibration(
        laser=f.laser,
        cameras={name: cam.calib(source, name) for name, cam in f.cameras.items()},
        laser_to_vehicle=None if f.laser_to_vehicle is None else f.laser_to_vehicle.rigid(),
        source=source,
    )


def load(path: str | Path, *, intrinsics_only: bool = False) -> Calibration:
    """Read and validate a calib.yaml; ``intrinsics_only``: for the cameras' models only
    (a camera may lack ``camera_to_laser``)."""
    path = Path(path)
    return parse(yamlcheck.read(path, CalibFileError), str(path), intrinsics_only=intrinsics_only)


def dump(calib: Calibration) -> str:
    """The YAML text of a calibration."""
    return yaml.safe_dump(calib.to_dict(), sort_keys=False, default_flow_style=None)


def merged(old: Calibration, new: Calibration, names: Sequence[str], source: str) -> Calibration:
    """``new``'s cameras ``names`` written into ``old`` (the calibration of the file
    ``source`` being updated): ``old``'s other cameras kept as they are, ``new``'s other
    cameras added where ``old`` lacks them; ``old``'s laser_to_vehicle, else ``new``'s.
    CalibFileError when the two are relative to different lasers."""
    if old.laser != new.laser:
        raise CalibFileError(
            f"{source}: its cameras are calibrated against laser {old.laser!r}, these against "
            f"{new.laser!r}; give another file"
        )
    cameras = dict(old.cameras)
    for name, cam in new.cameras.items():
        if name in names or name not in cameras:
            cameras[name] = cam
    ltv = old.laser_to_vehicle if old.laser_to_vehicle is not None else new.laser_to_vehicle
    return Calibration(old.laser, cameras, ltv)


def method_with(method: str, key: str, how: str) -> str:
    """A camera's ``method`` with the part on ``key`` (``"KEY: HOW"``, parts joined by
    ``"; "``) set to ``how``: what one calibration step changed said beside the others'
    (e.g. ``"simulator truth; time_offset_s: estimated from drive.mcap ..."``)."""
    parts = [p for p in method.split("; ") if p and not p.startswith(f"{key}: ")]
    return "; ".join([*parts, f"{key}: {how}"])


def save(calib: Calibration, path: str | Path) -> None:
    """Write a calibration atomically (a reader never sees half a file, two writers at
    once never mix theirs: :func:`acq.atomic_write.atomic`)."""
    with atomic(Path(path)) as tmp:
        tmp.write_text(dump(calib), encoding="utf-8")
