"""A procedural street, the vehicle's trajectory through it and the sensor rig.

World frame: x along the street (the vehicle drives +x), y left, z up, metres; the road
surface is the plane z = 0 and the street's centre line is y = 0. Every object is an
axis-aligned box standing in the street, a vertical cylinder, or a free textured quad
(for calibration boards and validation patterns), so the ray caster (``acq.sim.raycast``)
can cut the street into slices along x. Colours are BGR uint8.

The paper's §4.2 validation pattern (:func:`validation_pattern`) can stand in the street:
``Street.generate(..., pattern_at=x)`` puts it on the left sidewalk (the default camera's
side) and keeps that stretch of the left side clear of parked cars, poles and buildings.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

import numpy as np

from acq.camera.camera_models import KannalaBrandt
from acq.geometry.rotations import matrices_from_euler, rotation_from_euler
from acq.geometry.transforms import Rigid

__all__ = [
    "LEFT_PHOTOMETRY",
    "N_PARAMS",
    "PATTERN_BACK_Y",
    "PATTERN_CLEAR_M",
    "PATTERN_FRONT_Y",
    "REAR_PHOTOMETRY",
    "RIGHT_PHOTOMETRY",
    "Box",
    "Cylinder",
    "Material",
    "Photometry",
    "Quad",
    "Rig",
    "RigCamera",
    "Street",
    "Trajectory",
    "checkerboard_quad",
    "default_lens",
    "default_rig",
    "solid_quad",
    "validation_pattern",
]

N_PARAMS = 16  # material parameters per object (colours, pattern sizes), see Material

BGR = tuple[int, int, int]


class Material(IntEnum):
    """Surface kinds; the ray caster reports one per ray and shades by it.

    Parameters (``params``, up to ``N_PARAMS`` floats) by material:

    - FACADE: colour(3), frame colour(3), glass colour(3), window pitch along the facade,
      floor height, window width, window height, sill height, x phase, ground floor height
      (metres). Windows only on the faces looking along ±y.
    - SIDEWALK: tile colour(3), second tile colour(3), grout colour(3), tile size, grout
      width (metres), kerb colour(3).
    - CAR_BODY: colour(3). CAR_CABIN: body colour(3), glass colour(3), pillar width (m).
    - POLE: colour A(3), colour B(3), stripe length (m).
    - CHECKER: columns, rows, colour A(3), colour B(3) (square (0,0) has colour A).
    - SOLID: colour(3).
    """

    SKY = 0
    ROAD = 1  # the plane z = 0 (asphalt with markings on the road, paving beyond)
    SIDEWALK = 2
    FACADE = 3
    CAR_BODY = 4
    CAR_CABIN = 5
    POLE = 6
    CHECKER = 7
    SOLID = 8


def _params(*values: float) -> tuple[float, ...]:
    if len(values) > N_PARAMS:
        raise ValueError(f"at most {N_PARAMS} material parameters, got {len(values)}")
    return tuple(float(v) for v in values) + (0.0,) * (N_PARAMS - len(values))


@dataclass(frozen=True)
class Box:
    """An axis-aligned box (metres, world frame) with a material and its parameters."""

    xmin: float
    xmax: float
    ymin: float
    ymax: float
    zmin: float
    zmax: float
    material: Material
    params: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if not (self.xmin < self.xmax and self.ymin < self.ymax and self.zmin < self.zmax):
            raise ValueError(f"empty box {self}")
        object.__setattr__(self, "params", _params(*self.params))


@dataclass(frozen=True)
class Cylinder:
    """A vertical cylinder: axis at (x, y), radius and z range in metres."""

    x: float
    y: float
    radius: float
    zmin: float
    zmax: float
    material: Material
    params: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if not (self.radius > 0 and self.zmin < self.zmax):
            raise ValueError(f"empty cylinder {self}")
        object.__setattr__(self, "params", _params(*self.params))


@dataclass(frozen=True)
class Quad:
    """A planar parallelogram ``origin + a * u + b * v``, a and b in [0, 1] (metres).

    Any orientation; seen from both sides. CHECKER squares are counted along u (columns)
    and v (rows).
    """

    origin: tuple[float, float, float]
    u: tuple[float, float, float]
    v: tuple[float, float, float]
    material: Material
    params: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        n = np.cross(self.u, self.v)
        if np.linalg.norm(n) < 1e-12:
            raise ValueError("degenerate quad: u and v are parallel")
        object.__setattr__(self, "params", _params(*self.params))


def checkerboard_quad(
    origin: tuple[float, float, float],
    u_dir: tuple[float, float, float],
    v_dir: tuple[float, float, float],
    cols: int,
    rows: int,
    square: float,
    colours: tuple[BGR, BGR] = ((20, 20, 20), (235, 235, 235)),
) -> Quad:
    """A cols x rows checkerboard with ``square`` metre squares; u_dir, v_dir unit edges."""
    u = tuple(float(c) * cols * square for c in np.asarray(u_dir, float))
    v = tuple(float(c) * rows * square for c in np.asarray(v_dir, float))
    return Quad(origin, u, v, Material.CHECKER, (cols, rows, *colours[0], *colours[1]))  # type: ignore[arg-type]


def solid_quad(
    origin: tuple[float, float, float],
    u: tuple[float, float, float],
    v: tuple[float, float, float],
    colour: BGR,
) -> Quad:
    """A plain coloured quad (e.g. one set of the validation pattern)."""
    return Quad(origin, u, v, Material.SOLID, colour)


PATTERN_FRONT_Y = 5.0  # m, |y| of the validation pattern's bars (0.75 m behind the kerb)
PATTERN_BACK_Y = 6.0  # m, |y| of its back panel
PATTERN_CLEAR_M = 10.0  # m, Street.generate keeps x_m ± this clear on the pattern's side


def validation_pattern(
    x_m: float,
    side: int = 1,
    *,
    front_y: float = PATTERN_FRONT_Y,
    back_y: float = PATTERN_BACK_Y,
    bar_m: float = 0.25,
    gap_m: float = 0.2,
    n_bars: int = 6,
    bottom_m: float = 0.8,
    length_m: float = 3.0,
    square_m: float = 0.45,
    panel_cols: int = 9,
    panel_rows: int = 8,
    panel_bottom_m: float = 0.5,
    colours: Mapping[str, tuple[int, int, int]] | None = None,
) -> list[Quad]:
    """The paper's §4.2 validation pattern at street position ``x_m`` (m) on the
    ``side`` (+1 left, -1 right) of the street: two vertical planes parallel to it.

    Front set: ``n_bars`` horizontal bars ``bar_m`` tall and ``length_m`` long (centred on
    x_m), ``gap_m`` apart, the lowest from ``bottom_m`` above the road, alternately red
    and green (the lowest red), at |y| = ``front_y``. Back set: a panel of ``panel_cols``
    x ``panel_rows`` blue and yellow squares of ``square_m`` at |y| = ``back_y``, from
    ``panel_bottom_m`` above the road up (raised, so no laser point where it meets the
    ground lies on its plane); a square's centre lies on x = x_m (odd ``panel_cols``), so
    a scan plane x = x_m runs through square centres, not along a colour edge. The stands
    are not modelled. ``colours``: RGB by name as ``acq.calib.validate.DEFAULT_COLOURS`` (the
    default); metres.
    """
    if colours is None:
        from acq.calib.validate import DEFAULT_COLOURS  # here: 0.33 s with cv2; this 0.17 s

        colours = DEFAULT_COLOURS
    rgb = colours
    if side not in (1, -1):
        raise ValueError(f"side must be +1 or -1, got {side}")
    if panel_cols % 2 == 0:
        raise ValueError("panel_cols must be odd (a square centred on x_m)")

    def bgr(name: str) -> BGR:
        r, g, b = rgb[name]
        return (b, g, r)

    x0 = x_m - length_m / 2
    bars = [
        solid_quad(
            (x0, side * front_y, bottom_m + k * (bar_m + gap_m)),
            (length_m, 0.0, 0.0),
            (0.0, 0.0, bar_m),
            bgr("red" if k % 2 == 0 else "green"),
        )
        for k in range(n_bars)
    ]
    panel = checkerboard_quad(
        (x_m - panel_cols * square_m / 2, side * back_y, panel_bottom_m),
        (1.0, 0.0, 0.0),
        (0.0, 0.0, 1.0),
        panel_cols,
        panel_rows,
        square_m,
        (bgr("blue"), bgr("yellow")),
    )
    return [*bars, panel]


# --- the street -------------------------------------------------------------------------

ROAD_HALF_WIDTH = 4.25  # m, kerb line; driving lanes up to ±3.0, parking beyond
LANE_EDGE = 3.0  # m, solid edge lines
SIDEWALK_HEIGHT = 0.15  # m

_FACADE_COLOURS: tuple[BGR, ...] = (
    (120, 170, 215),  # ochre
    (170, 190, 205),  # beige
    (80, 90, 170),  # brick red
    (190, 190, 185),  # light grey
    (150, 200, 160),  # pale green
    (200, 160, 130),  # blue-grey
    (110, 140, 200),  # salmon
    (215, 225, 230),  # off-white
)
_CAR_COLOURS: tuple[BGR, ...] = (
    (40, 40, 200),
    (200, 90, 30),
    (235, 235, 235),
    (40, 40, 40),
    (60, 180, 220),
    (80, 140, 60),
    (160, 160, 165),
)
_POLE_COLOURS: tuple[tuple[BGR, BGR], ...] = (
    ((30, 30, 220), (240, 240, 240)),
    ((20, 200, 240), (30, 30, 30)),
)


@dataclass
class Street:
    """The scene: boxes, vertical cylinders and free quads over the ground plane z = 0.

    Add objects with :meth:`add` (calibration boards, validation patterns); the ray
    caster packs the scene again after any change.
    """

    boxes: list[Box] = field(default_factory=list)
    cylinders: list[Cylinder] = field(default_factory=list)
    quads: list[Quad] = field(default_factory=list)
    length_m: float = 0.0
    road_half_width: float = ROAD_HALF_WIDTH
    lane_edge: float = LANE_EDGE
    seed: int | None = None
    version: int = 0  # bumped by add(); the caster's cache key

    def add(self, *objects: Box | Cylinder | Quad) -> None:
        """Add objects to the scene."""
        for obj in objects:
            if isinstance(obj, Box):
                self.boxes.append(obj)
            elif isinstance(obj, Cylinder):
                self.cylinders.append(obj)
            elif isinstance(obj, Quad):
                self.quads.append(obj)
            else:
                raise TypeError(f"cannot add {type(obj).__name__} to a street")
        self.version += 1

    @classmethod
    def generate(
        cls, seed: int = 0, length_m: float = 200.0, pattern_at: float | None = None
    ) -> Street:
        """A random street from x = -40 to ``length_m + 40`` m (the vehicle starts at 0).

        With ``pattern_at`` (x, m) the validation pattern (:func:`validation_pattern`,
        default placement) stands there on the left sidewalk, and the left side within
        ``PATTERN_CLEAR_M`` of it is cleared of parked cars, poles and buildings (cut back
        to the stretch's ends); the rest of the street is the one without the pattern.
        """
        rng = np.random.default_rng(seed)
        street = cls(length_m=length_m, seed=seed)
        x0, x1 = -40.0, length_m + 40.0
        w = street.road_half_width
        for side in (1.0, -1.0):
            street._sidewalk(side, x0, x1)
            street._buildings(rng, side, x0, x1)
            street._back_row(rng, side, x0, x1)
            street._cars(rng, side, x0, x1, w)
            street._poles(rng, side, x0, x1, w)
        if pattern_at is not None:
            street._clear(pattern_at - PATTERN_CLEAR_M, pattern_at + PATTERN_CLEAR_M, 1.0)
            street.quads.extend(validation_pattern(pattern_at))
        street.version += 1
        return street

    def _clear(self, x0: float, x1: float, side: float) -> None:
        """Remove parked cars and poles from x0..x1 (m) on ``side``, cut buildings back."""

        def on_side(ylo: float, yhi: float) -> bool:
            return ylo >= 0.0 if side > 0 else yhi <= 0.0

        boxes: list[Box] = []
        gone: list[Box] = []  # car bodies removed: their cabins go too
        for b in self.boxes:
            if not on_side(b.ymin, b.ymax) or b.xmax <= x0 or b.xmin >= x1:
                boxes.append(b)
            elif b.material == Material.FACADE:
                if b.xmin < x0:
                    boxes.append(dataclasses.replace(b, xmax=x0))
                if b.xmax > x1:  # windows stay where they were (x phase, params[14])
                    params = (*b.params[:14], b.params[14] + b.xmin - x1, *b.params[15:])
                    boxes.append(dataclasses.replace(b, xmin=x1, params=params))
            elif b.material == Material.CAR_BODY:
                gone.append(b)
            elif b.material != Material.CAR_CABIN:
                boxes.append(b)  # the sidewalk
        self.boxes = [
            b
            for b in boxes
            if b.material != Material.CAR_CABIN
            or not any(g.xmin <= b.xmin and b.xmax <= g.xmax and g.ymin < b.ymin < g.ymax
                       for g in gone)
        ]  # fmt: skip
        self.cylinders = [
            c
            for c in self.cylinders
            if not (on_side(c.y - c.radius, c.y + c.radius) and x0 <= c.x <= x1)
        ]

    def _sidewalk(self, side: float, x0: float, x1: float) -> None:
        y_in, y_out = self.road_half_width, 30.0
        ylo, yhi = (y_in, y_out) if side > 0 else (-y_out, -y_in)
        params = _params(
            *(175, 178, 182), *(150, 158, 165), *(95, 95, 100), 0.5, 0.05, *(200, 200, 200)
        )
        self.boxes.append(Box(x0, x1, ylo, yhi, 0.0, SIDEWALK_HEIGHT, Material.SIDEWALK, params))

    def _buildings(self, rng: np.random.Generator, side: float, x0: float, x1: float) -> None:
        x = x0
        while x < x1:
            width = min(rng.uniform(8.0, 25.0), x1 - x)
            dist = rng.uniform(5.5, 10.0)
            depth = rng.uniform(8.0, 14.0)
            height = rng.uniform(10.0, 30.0)
            colour = np.array(_FACADE_COLOURS[rng.integers(len(_FACADE_COLOURS))], float)
            colour = np.clip(colour + rng.integers(-12, 13, 3), 0, 255)
            frame = (235, 235, 235) if rng.random() < 0.6 else (70, 60, 55)
            glass = (55 + rng.integers(0, 20), 45 + rng.integers(0, 10), 35)
            pitch = rng.uniform(2.2, 3.2)
            floor_h = rng.uniform(2.9, 3.5)
            params = (
                *colour,
                *frame,
                *glass,
                pitch,
                floor_h,
                rng.uniform(0.9, min(1.5, pitch - 0.6)),
                rng.uniform(1.3, min(1.8, floor_h - 1.0)),
                rng.uniform(0.8, 1.0),
                rng.uniform(0.0, pitch),
                rng.uniform(3.5, 4.5),
            )
            ylo, yhi = (dist, dist + depth) if side > 0 else (-dist - depth, -dist)
            if width >= 2.0:
                self.boxes.append(Box(x, x + width, ylo, yhi, 0.0, height, Material.FACADE, params))
            x += width
            if rng.random() < 0.25:
                x += rng.uniform(2.5, 6.0)  # an alley

    def _back_row(self, rng: np.random.Generator, side: float, x0: float, x1: float) -> None:
        x = x0
        while x < x1:
            width = min(rng.uniform(30.0, 60.0), x1 - x)
            colour = _FACADE_COLOURS[rng.integers(len(_FACADE_COLOURS))]
            params = (*colour, 200, 200, 200, 60, 55, 50, 3.0, 3.2, 1.2, 1.5, 0.9, 0.0, 4.0)
            ylo, yhi = (24.0, 34.0) if side > 0 else (-34.0, -24.0)
            height = rng.uniform(12.0, 35.0)
            self.boxes.append(Box(x, x + width, ylo, yhi, 0.0, height, Material.FACADE, params))
            x += width

    def _cars(self, rng: np.random.Generator, side: float, x0: float, x1: float, w: float) -> None:
        x = x0 + rng.uniform(0.0, 6.0)
        while x < x1 - 6.0:
            if rng.random() < 0.45:
                length = rng.uniform(3.9, 4.8)
                width = rng.uniform(1.7, 1.9)
                yc = side * (w - 0.15 - width / 2)
                colour = _CAR_COLOURS[rng.integers(len(_CAR_COLOURS))]
                ylo, yhi = yc - width / 2, yc + width / 2
                body_top = rng.uniform(0.9, 1.0)
                self.boxes.append(
                    Box(x, x + length, ylo, yhi, 0.2, body_top, Material.CAR_BODY, colour)
                )
                front, rear = (0.9, 0.7) if side > 0 else (0.7, 0.9)  # cars face the traffic
                self.boxes.append(
                    Box(
                        x + rear,
                        x + length - front,
                        ylo + 0.08,
                        yhi - 0.08,
                        body_top,
                        body_top + rng.uniform(0.45, 0.55),
                        Material.CAR_CABIN,
                        (*colour, 35, 30, 30, 0.12),
                    )
                )
                x += length + rng.uniform(0.8, 2.5)
            else:
                x += rng.uniform(3.0, 8.0)

    def _poles(self, rng: np.random.Generator, side: float, x0: float, x1: float, w: float) -> None:
        x = x0 + rng.uniform(5.0, 20.0)
        while x < x1:
            a, b = _POLE_COLOURS[rng.integers(len(_POLE_COLOURS))]
            self.cylinders.append(
                Cylinder(
                    x,
                    side * (w + 0.45),
                    rng.uniform(0.05, 0.09),
                    SIDEWALK_HEIGHT,
                    rng.uniform(4.0, 8.0),
                    Material.POLE,
                    (*a, *b, rng.uniform(0.3, 0.6)),
                )
            )
            x += rng.uniform(15.0, 35.0)


# --- the vehicle's motion ---------------------------------------------------------------


@dataclass(frozen=True)
class Trajectory:
    """Smooth analytic vehicle motion: vehicle (base_link) -> world at time t (s).

    The vehicle drives +x at ``speed`` m/s from ``x0`` in the lane at ``y0``. Options: a
    lateral sine of ``curve_amplitude`` m over ``curve_wavelength`` m of x (yaw follows the
    tangent; x still advances at ``speed``), and body roll/pitch vibration of
    ``vibration_rad`` amplitude with seeded frequencies (1-3 Hz) and phases.
    """

    speed: float = 20.0 / 3.6
    x0: float = 0.0
    y0: float = -1.5
    curve_amplitude: float = 0.0
    curve_wavelength: float = 120.0
    vibration_rad: float = 0.0
    seed: int = 0

    def _vibration(self) -> np.ndarray:
        """(2, 2) rows roll, pitch of (frequency Hz, phase rad), from the seed."""
        rng = np.random.default_rng(self.seed + 7919)
        return np.stack([rng.uniform(1.0, 3.0, 2), rng.uniform(0.0, 2 * math.pi, 2)], axis=1)

    def poses(self, ts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Vehicle -> world for times ``ts`` (s): rotations (N,3,3) and translations (N,3) m."""
        ts = np.atleast_1d(np.asarray(ts, dtype=np.float64))
        x = self.x0 + self.speed * ts
        k = 2 * math.pi / self.curve_wavelength
        y = self.y0 + self.curve_amplitude * np.sin(k * (x - self.x0))
        yaw = np.arctan(self.curve_amplitude * k * np.cos(k * (x - self.x0)))
        if self.vibration_rad:
            vib = self._vibration()
            roll = self.vibration_rad * np.sin(2 * math.pi * vib[0, 0] * ts + vib[0, 1])
            pitch = self.vibration_rad * np.sin(2 * math.pi * vib[1, 0] * ts + vib[1, 1])
        else:
            roll = pitch = np.zeros_like(ts)
        R = matrices_from_euler(roll, pitch, yaw)
        t = np.stack([x, y, np.zeros_like(x)], axis=1)
        return R, t

    def pose(self, t: float) -> Rigid:
        """Vehicle -> world at time t (s): ``P_world = R @ P_vehicle + t``."""
        R, tr = self.poses(np.array([t]))
        return Rigid(R[0], tr[0])


# --- the rig ----------------------------------------------------------------------------


def default_lens(exact_equidistant: bool = False) -> KannalaBrandt:
    """The simulated 185-degree fisheye: 780x582 px, f 169.3 px/rad.

    By default a Kannala-Brandt lens whose distance from ``r = f·theta`` stays below 1, 2,
    3, 4 px up to 53.75, 67.75, 77.5, 85.4 degrees (the paper's Table 3); with
    ``exact_equidistant`` all coefficients are zero.
    """
    k = (0.0, 0.0, 0.0, 0.0) if exact_equidistant else (0.0068, 0.0004, -0.0002, 0.00003)
    return KannalaBrandt(
        width=780, height=582, fx=169.3, fy=169.3, cx=390.2, cy=291.1, k=k, fov_deg=185.0
    )


@dataclass(frozen=True)
class Photometry:
    """How a camera renders brightness over the drive: per-channel gains (BGR) at time t
    (s from the drive's start) multiplying the surface colour, as auto-exposure and
    auto-white-balance do.

    ``white_balance`` (3,) the camera's own channel gains; ``wb_drift`` (3,) the
    amplitude of a slow sinusoidal drift of each channel over ``wb_period_s`` s (phase
    ``wb_phase`` rad); ``steps`` ((t, gain), ...) auto-exposure steps: from t on, the
    exposure gain is ``gain`` (1 before the first); ``clouds`` ((t, half_width_s,
    depth), ...) a cloud passing: the light dims by ``depth`` (0.2: 20 %) at t, smoothly
    (a raised cosine) over t ± half_width_s.
    """

    white_balance: tuple[float, float, float] = (1.0, 1.0, 1.0)
    wb_drift: tuple[float, float, float] = (0.0, 0.0, 0.0)
    wb_period_s: float = 40.0
    wb_phase: float = 0.0
    steps: tuple[tuple[float, float], ...] = ()
    clouds: tuple[tuple[float, float, float], ...] = ()

    @property
    def constant(self) -> bool:
        """Whether the gains are 1 throughout (nothing to apply)."""
        return (
            self.white_balance == (1.0, 1.0, 1.0)
            and not any(self.wb_drift)
            and not self.steps
            and not self.clouds
        )

    def gains(self, t: float | np.ndarray) -> np.ndarray:
        """(..., 3) BGR gains at time(s) ``t`` (s)."""
        t = np.asarray(t, dtype=np.float64)
        exposure = np.ones_like(t)
        for when, gain in sorted(self.steps):
            exposure = np.where(t >= when, gain, exposure)
        for when, half, depth in self.clouds:
            x = np.clip((t - when) / half, -1.0, 1.0)
            exposure = exposure * (1.0 - depth * 0.5 * (1.0 + np.cos(math.pi * x)))
        phase = 2 * math.pi * t / self.wb_period_s + self.wb_phase
        wb = np.asarray(self.white_balance) * (
            1.0 + np.asarray(self.wb_drift) * np.sin(phase)[..., None]
        )
        out: np.ndarray = exposure[..., None] * wb
        return out


@dataclass(frozen=True)
class RigCamera:
    """One camera of the rig: its ``name`` (topics ``/<name>/...``), mounting
    (``camera_to_laser``: P_laser = R @ P_camera + t, paper eq. 2; camera optical frame:
    z along the axis, x right, y down), ``lens``, ``latency_s`` (end of exposure ->
    frame available, s), ``exposure`` s and :class:`Photometry`."""

    name: str
    camera_to_laser: Rigid
    lens: KannalaBrandt
    latency_s: float = 0.020
    exposure: float = 0.004
    photometry: Photometry = Photometry()


@dataclass(frozen=True)
class Rig:
    """The simulated sensors and their mounting (the truth).

    ``laser_to_vehicle``: P_vehicle = R @ P_laser + t. ``cameras``: one or more
    :class:`RigCamera`; ``lens``, ``camera_to_laser`` and ``exposure`` are the first
    one's (what single-camera code uses; :meth:`only` makes a rig of any one camera).
    Scanner: REP-103 angles (rad), ``scan_period`` s per rotation, ``time_increment``
    s per step, ranges in metres with Gaussian noise of ``range_noise`` m. Cameras:
    ``fps`` frames per second.
    """

    laser_to_vehicle: Rigid
    cameras: tuple[RigCamera, ...]
    angle_min: float = math.radians(-135.0)
    angle_increment: float = math.radians(0.25)
    n_steps: int = 1081
    scan_period: float = 0.025
    time_increment: float = 0.025 / 1440
    max_range: float = 30.0
    min_range: float = 0.1
    range_noise: float = 0.01
    fps: float = 25.0

    def __post_init__(self) -> None:
        names = [c.name for c in self.cameras]
        if not names or len(set(names)) != len(names):
            raise ValueError(f"a rig needs cameras with distinct names, got {names}")

    @property
    def angles(self) -> np.ndarray:
        """(n_steps,) scan angles, rad."""
        return self.angle_min + self.angle_increment * np.arange(self.n_steps)

    @property
    def camera_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.cameras)

    def camera(self, name: str | None = None) -> RigCamera:
        """The camera ``name`` (None: the first); KeyError naming the rig's cameras."""
        if name is None:
            return self.cameras[0]
        for c in self.cameras:
            if c.name == name:
                return c
        raise KeyError(f"no camera {name!r} on the rig (has {', '.join(self.camera_names)})")

    def only(self, name: str) -> Rig:
        """This rig with only the camera ``name``."""
        return dataclasses.replace(self, cameras=(self.camera(name),))

    def with_camera(self, name: str | None = None, **changes: Any) -> Rig:
        """This rig with camera ``name``'s (None: the first's) fields ``changes``
        (:class:`RigCamera`'s: ``lens``, ``camera_to_laser``...) replaced."""
        cam = self.camera(name)
        new = dataclasses.replace(cam, **changes)
        return dataclasses.replace(
            self, cameras=tuple(new if c is cam else c for c in self.cameras)
        )

    @property
    def lens(self) -> KannalaBrandt:
        return self.cameras[0].lens

    @property
    def camera_to_laser(self) -> Rigid:
        return self.cameras[0].camera_to_laser

    @property
    def exposure(self) -> float:
        return self.cameras[0].exposure

    def camera_to_vehicle(self, name: str | None = None) -> Rigid:
        """Camera ``name``'s (None: the first's) optical frame -> vehicle."""
        return self.laser_to_vehicle @ self.camera(name).camera_to_laser


# laser x = vehicle up, laser y = vehicle right, laser z = vehicle forward
_LASER_AXES = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])
# left camera: x = vehicle forward, y = vehicle down, z (optical axis) = vehicle left
_CAMERA_AXES = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
# right camera: x = vehicle backward, y = vehicle down, z (optical axis) = vehicle right
_RIGHT_AXES = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, -1.0, 0.0]])


def _right_lens() -> KannalaBrandt:
    """The right camera's fisheye: the same make, its own centre, focal length and
    distortion (a second unit of one model)."""
    return KannalaBrandt(
        width=780, height=582, fx=168.6, fy=168.6, cx=388.7, cy=292.6,
        k=(0.0061, 0.0006, -0.00025, 0.00004), fov_deg=185.0,
    )  # fmt: skip


# Each camera's auto-exposure and white balance over the drive (s from its start): its
# own white balance drifting slowly, and exposure that hunts around the right one (steps
# away and back, as an auto-exposure loop does); a cloud dims every camera at once. The
# cameras' white balances straddle neutral and each camera's exposure is the right one
# most of the time: the truth is the reference acq.cloud.balance balances to.
LEFT_PHOTOMETRY = Photometry(
    white_balance=(0.95, 1.0, 1.05),
    wb_drift=(0.01, 0.0, -0.01),
    wb_period_s=47.0,
    steps=((9.0, 1.1), (15.0, 1.0), (27.0, 0.92), (33.0, 1.0), (44.0, 1.07), (49.0, 1.0)),
    clouds=((31.0, 4.0, 0.2),),
)
RIGHT_PHOTOMETRY = Photometry(
    white_balance=(1 / 0.95, 1.0, 1 / 1.05),
    wb_drift=(-0.01, 0.0, 0.01),
    wb_period_s=53.0,
    wb_phase=1.3,
    steps=(
        (13.0, 0.9),
        (19.0, 1.0),
        (24.0, 1.08),
        (29.0, 1.0),
        (38.0, 0.94),
        (45.0, 1.0),
        (52.0, 1.1),
        (57.0, 1.0),
    ),
    clouds=((31.5, 4.0, 0.2),),
)
REAR_PHOTOMETRY = Photometry(
    wb_drift=(0.01, 0.0, 0.01),
    wb_period_s=41.0,
    steps=((21.0, 1.09), (26.0, 1.0), (47.0, 0.93), (53.0, 1.0)),
    clouds=((31.2, 4.0, 0.2),),
)
# rear camera: x = vehicle left, y = down (and a little forward), z (optical axis) =
# backward and 15 degrees down
_S, _C = math.sin(math.radians(15.0)), math.cos(math.radians(15.0))
_REAR_AXES = np.array([[0.0, _S, -_C], [1.0, 0.0, 0.0], [0.0, -_C, -_S]])


def default_rig(exact_equidistant: bool = False, cameras: int = 1) -> Rig:
    """UTM-30LX at the rear of the roof (2.2 m) scanning across the street, and a
    fisheye 0.4 m ahead of it, 0.25 m lower, looking left with a small tilt.

    ``cameras=1``: that camera alone, named ``camera``, with constant photometry (the
    rig of the single-camera tests). ``cameras=2``: ``left`` (the same camera) and
    ``right`` (its mirror image: looking right, its own mounting error, lens, latency),
    each with its own exposure and white balance changing over the drive. The two see
    no laser point together (the scanner is blind below the car, where they overlap);
    ``cameras=3`` adds ``rear``, on the roof 0.9 m ahead of the scan plane looking back
    at it and 15 degrees down, which sees both sides of the street near its rim."""
    if cameras not in (1, 2, 3):
        raise ValueError(f"the simulated rig has 1, 2 or 3 cameras, not {cameras}")
    laser_to_vehicle = Rigid(_LASER_AXES, np.array([-0.6, 0.0, 2.2]))
    tilt = rotation_from_euler(math.radians(1.2), math.radians(-1.5), math.radians(0.8))
    left_to_vehicle = Rigid(tilt @ _CAMERA_AXES, np.array([-0.2, 0.12, 1.95]))
    vehicle_to_laser = laser_to_vehicle.inverse()
    left = RigCamera(
        name="camera" if cameras == 1 else "left",
        camera_to_laser=vehicle_to_laser @ left_to_vehicle,
        lens=default_lens(exact_equidistant),
        photometry=Photometry() if cameras == 1 else LEFT_PHOTOMETRY,
    )
    if cameras == 1:
        return Rig(laser_to_vehicle=laser_to_vehicle, cameras=(left,))
    tilt_r = rotation_from_euler(math.radians(-0.9), math.radians(1.1), math.radians(-0.7))
    right_to_vehicle = Rigid(tilt_r @ _RIGHT_AXES, np.array([-0.18, -0.13, 1.96]))
    right = RigCamera(
        name="right",
        camera_to_laser=vehicle_to_laser @ right_to_vehicle,
        lens=default_lens(True) if exact_equidistant else _right_lens(),
        latency_s=0.026,
        photometry=RIGHT_PHOTOMETRY,
    )
    if cameras == 2:
        return Rig(laser_to_vehicle=laser_to_vehicle, cameras=(left, right))
    tilt_b = rotation_from_euler(math.radians(0.6), math.radians(0.8), math.radians(-1.1))
    rear_to_vehicle = Rigid(tilt_b @ _REAR_AXES, np.array([0.3, 0.02, 2.1]))
    rear = RigCamera(
        name="rear",
        camera_to_laser=vehicle_to_laser @ rear_to_vehicle,
        lens=default_lens(exact_equidistant),
        latency_s=0.023,
        photometry=REAR_PHOTOMETRY,
    )
    return Rig(laser_to_vehicle=laser_to_vehicle, cameras=(left, right, rear))
