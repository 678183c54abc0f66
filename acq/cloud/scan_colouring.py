"""The colouring core: laser points placed at their own time (:func:`place`), each
camera's frames around them made ready (:func:`camera_frames`), coloured by every camera
(:func:`start`, on a pool's threads) and the cameras merged into one colour per point
(:func:`merge`). ``acq colorize`` runs it per chunk of a session
(:mod:`acq.cloud.chunks`, which numbers scans and frames over the session); the recorder
runs it per scan as the scans come (:mod:`acq.record.live_colour`), through
:func:`colour_scans`. Both hand it plain arrays: no log, no session.

Times host ns (the log's clock) unless ``_s``; metres; colours RGB uint8.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import Executor, Future
from dataclasses import dataclass, field
from typing import Any, ParamSpec, TypeVar

import numpy as np

from acq.camera.calibfile import CameraCalib
from acq.camera.jpeg import SharedDecodes
from acq.cloud import balance, multiview, views
from acq.geometry.transforms import Rigid
from acq.motion.pose_source import PoseSource
from acq.time import sync

__all__ = [
    "Beams",
    "CameraFrames",
    "Inline",
    "Merged",
    "Placed",
    "camera_frames",
    "colour_scans",
    "merge",
    "place",
    "start",
]


_P = ParamSpec("_P")
_T = TypeVar("_T")


class Inline(Executor):
    """Runs each task at once on the caller's thread: one scan's few frames colour
    faster there than handed to a pool's threads and back (each hand-over wakes a thread
    and waits for the GIL)."""

    def submit(self, fn: Callable[_P, _T], /, *args: _P.args, **kwargs: _P.kwargs) -> Future[_T]:
        future: Future[_T] = Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as e:
            future.set_exception(e)
        return future


@dataclass(frozen=True)
class Beams:
    """A scanner's beams: beam ``k`` points at ``angle_min + k * angle_increment`` rad
    and is measured ``k * time_increment`` s after beam 0."""

    angle_min: float
    angle_increment: float
    time_increment: float


@dataclass(frozen=True)
class Placed:
    """Points in time order: ``scan`` and ``step`` (N,) indices into the scans and beams
    given, ``r`` (N,) m, ``time_ns`` (N,), ``P_laser`` (N,3) in the laser frame at their
    own time, ``P_world`` (N,3) placed with the poses (NaN without a pose there;
    ``P_laser`` without poses), ``inside`` (N,) whether it had one."""

    scan: np.ndarray
    step: np.ndarray
    r: np.ndarray
    time_ns: np.ndarray
    P_laser: np.ndarray
    P_world: np.ndarray
    inside: np.ndarray


def place(
    ranges: np.ndarray, scan_ns: np.ndarray, beams: Beams, keep: np.ndarray | None,
    poses: PoseSource | None, laser_to_vehicle: Rigid,
) -> Placed:  # fmt: skip
    """The finite returns of ``ranges`` (S,B) m of the scans ``keep`` (S,) bool (None:
    all), whose point 0 was measured at ``scan_ns`` (S,), each at its own time."""
    if keep is not None:
        ranges = np.where(keep[:, None], ranges, np.nan)
    scan_idx, step = np.nonzero(np.isfinite(ranges))
    r = ranges[scan_idx, step].astype(np.float64)
    angles = beams.angle_min + beams.angle_increment * np.arange(ranges.shape[1])
    P_laser = np.zeros((r.size, 3))  # filled in place: no (N,) temporaries
    np.multiply(r, np.cos(angles)[step], out=P_laser[:, 0])
    np.multiply(r, np.sin(angles)[step], out=P_laser[:, 1])
    time_ns = sync.point_times_ns(scan_ns[scan_idx], beams.time_increment, step)
    if time_ns.size and np.any(np.diff(time_ns) < 0):  # scans out of order, or overlapping
        order = np.argsort(time_ns, kind="stable")
        scan_idx, step, P_laser, time_ns, r = (
            scan_idx[order], step[order], P_laser[order], time_ns[order], r[order]
        )  # fmt: skip
    inside = np.ones(time_ns.size, dtype=bool)
    P_world = P_laser
    if poses is not None:
        inside = poses.covers(time_ns)
        if inside.all():
            P_world = poses.transform(time_ns, laser_to_vehicle.apply(P_laser))
        else:
            P_world = np.full_like(P_laser, np.nan)  # no pose: not placed, not coloured
            P_world[inside] = poses.transform(
                time_ns[inside], laser_to_vehicle.apply(P_laser[inside])
            )
    return Placed(scan_idx, step, r, time_ns, P_laser, P_world, inside)


@dataclass(frozen=True)
class CameraFrames:
    """One camera's frames ready to colour from: ``stamp_ns`` (M,) as recorded (sorted),
    ``frame_ns`` (M,) the same on the laser's clock (:func:`acq.time.sync.on_laser_clock`),
    ``jpegs`` their bytes (or images decoded), ``usable`` (M,) bool (a pose at their
    time, the model's size), ``odd_size``: index -> (width, height) px of those of
    another size."""

    name: str
    cam: CameraCalib
    stamp_ns: np.ndarray
    frame_ns: np.ndarray
    jpegs: Sequence[views.Frame]
    usable: np.ndarray
    odd_size: dict[int, tuple[int, int]] = field(default_factory=dict)


def camera_frames(
    name: str, cam: CameraCalib, stamp_ns: np.ndarray, jpegs: Sequence[views.Frame],
    time_offset_ns: int, poses: PoseSource | None,
) -> CameraFrames:  # fmt: skip
    """Camera ``name``'s frames stamped ``stamp_ns`` (sorted) with bytes ``jpegs``: their
    times on the laser's clock, and which may be used (those ``poses`` covers, when
    given; not those whose JPEG header gives another size than ``cam``'s model)."""
    frame_ns = sync.on_laser_clock(stamp_ns, time_offset_ns)
    usable = poses.covers(frame_ns) if poses is not None else np.ones(frame_ns.size, bool)
    odd = views.odd_sized(jpegs, cam.model)
    if odd:
        usable[list(odd)] = False
    return CameraFrames(name, cam, stamp_ns, frame_ns, jpegs, usable, odd)


def start(
    pts: Placed, size_m: np.ndarray, cameras: Sequence[CameraFrames],
    poses: PoseSource | None, laser_to_vehicle: Rigid, options: views.Options, *,
    pool: Executor, need: np.ndarray | None = None, want_uv: bool = False,
    want_crops: bool = False, decodes: SharedDecodes | None = None,
) -> list[views.Colouring]:  # fmt: skip
    """Colour ``pts`` from every camera of ``cameras`` (frames queued on ``pool``, not
    waited for): in the world, sent back to where the rig stood at each frame's time,
    when there are ``poses`` and ``options`` compensate motion; ``need`` the points to
    colour (default all; the others only hide points in ``best``'s depth buffers);
    ``want_uv``, ``want_crops``, ``decodes``: as :func:`views.start_colouring` takes
    them."""
    compensate = poses is not None and options.motion_compensation
    pose_at = poses.pose_at if poses is not None else None
    return [
        views.start_colouring(
            pts.P_world if compensate else pts.P_laser,
            pts.time_ns,
            size_m,
            c.frame_ns,
            c.jpegs,
            c.cam,
            laser_to_vehicle,
            pose_at,
            options,
            pool=pool,
            want_uv=want_uv,
            want_crops=want_crops,
            decodes=decodes,
            frame_ok=c.usable,
            need=need,
        )
        for c in cameras
    ]


@dataclass(frozen=True)
class Merged:
    """The cameras' colours merged, per point: ``camera`` (N,) int64 the index of the
    camera it was coloured from (-1 none), ``rgb`` (N,3), ``coloured`` (N,), ``hidden``
    (N,) (seen by a camera but hidden in every frame), ``frame`` (N,) int64 the index of
    its frame among that camera's frames given (-1), ``dt_s`` and ``theta`` (N,) float32
    (NaN), ``uv`` (N,2) float32 px (with ``want_uv``); ``cols`` each camera's own
    colours, ``rgbs`` those balanced (with ``want_uv`` or blending; else empty),
    ``gains`` the balance (None: off)."""

    camera: np.ndarray
    rgb: np.ndarray
    coloured: np.ndarray
    hidden: np.ndarray
    frame: np.ndarray
    dt_s: np.ndarray
    theta: np.ndarray
    uv: np.ndarray | None
    cols: list[views.Coloured]
    rgbs: list[np.ndarray]
    gains: balance.Gains | None


def merge(
    cols: Sequence[views.Coloured], cameras: Sequence[CameraFrames], options: views.Options,
    n: int, *, want_uv: bool = False,
) -> Merged:  # fmt: skip
    """Each camera's colours of the same ``n`` points (``cols``, one per camera of
    ``cameras``) balanced (:mod:`acq.cloud.balance`, when ``options.balance``) and one
    camera chosen per point (:mod:`acq.cloud.multiview`)."""
    cols = list(cols)
    if not cols:
        none = np.full(n, -1, dtype=np.int64)
        nan = np.full(n, np.nan, dtype=np.float32)
        return Merged(
            none, np.zeros((n, 3), np.uint8), np.zeros(n, bool), np.zeros(n, bool), none,
            nan, nan, None, [], [], None,
        )  # fmt: skip
    gains = (
        balance.estimate_gains(cols, [c.frame_ns.size for c in cameras])
        if options.balance
        else None
    )
    models = [c.cam.model for c in cameras]
    uv = None
    if want_uv or options.blend:  # every camera's balanced colours are kept or blended
        rgbs = [
            gains.apply(c, col.rgb, col.frame) if gains is not None else col.rgb
            for c, col in enumerate(cols)
        ]
    else:
        rgbs = []
    if not options.blend:  # one pass per camera: its colours balanced only where chosen
        scales = [None if gains is None else gains.scales(c) for c in range(len(cols))]
        p = multiview.pick(cols, models, options.max_dt_s, scales)
        cam_idx, rgb, frame, dt_s, theta = p.camera, p.rgb, p.frame, p.dt_s, p.theta
        coloured, hidden = p.coloured, p.hidden
    else:
        choice = multiview.choose(cols, rgbs, models, options.max_dt_s, blend=True)
        cam_idx, rgb, coloured = choice.camera, choice.rgb, choice.coloured
        pick = np.maximum(cam_idx, 0)
        rows = np.arange(n)

        def chosen(name: str, fill: Any) -> np.ndarray:
            stack = np.stack([getattr(col, name) for col in cols])
            out: np.ndarray = np.where(cam_idx >= 0, stack[pick, rows], fill)
            return out

        frame = chosen("frame", -1)
        dt_s = chosen("dt_s", np.nan).astype(np.float32)
        theta = chosen("theta", np.nan).astype(np.float32)
        hidden = np.any(np.stack([col.hidden for col in cols]), axis=0) & ~coloured
    if want_uv:
        uv = np.stack([col.uv for col in cols])[np.maximum(cam_idx, 0), np.arange(n)]  # type: ignore[misc]
        uv[cam_idx < 0] = np.nan
    return Merged(
        camera=cam_idx,
        rgb=rgb,
        coloured=coloured,
        hidden=hidden,
        frame=frame,
        dt_s=dt_s,
        theta=theta,
        uv=uv,
        cols=cols,
        rgbs=rgbs,
        gains=gains,
    )


def colour_scans(
    ranges: np.ndarray,
    scan_ns: np.ndarray,
    beams: Beams,
    cameras: Sequence[CameraFrames],
    poses: PoseSource | None,
    laser_to_vehicle: Rigid,
    options: views.Options,
    *,
    pool: Executor,
    travel_m: float = 0.0,
) -> tuple[Placed, Merged]:
    """Scans ``ranges`` (S,B) m, point 0 at ``scan_ns`` (S,), placed and coloured from
    ``cameras`` (waiting for their frames): what the recorder does with each scan."""
    pts = place(ranges, scan_ns, beams, None, poses, laser_to_vehicle)
    size = views.point_size(pts.r, beams.angle_increment, travel_m)
    cols = start(pts, size, cameras, poses, laser_to_vehicle, options, pool=pool)
    return pts, merge([c.result() for c in cols], cameras, options, pts.time_ns.size)
