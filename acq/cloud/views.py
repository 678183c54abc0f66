"""Which camera frame colours each laser point (``acq colorize --view``), and its colour.

Every point is placed at its own time; the frame it is coloured from was exposed at
another instant, when the rig stood elsewhere. With a trajectory, the point goes back
into the camera as the rig stood at the frame's time (motion compensation: world ->
vehicle at the frame's time -> laser -> camera); without one (or with
``motion_compensation=False``) the point stays where the laser saw it relative to the
rig, which is right only for a rig standing still.

- ``nearest``: the frame nearest in time, within ``max_dt_s``.
- ``best``: among the ``window`` frames either side of the nearest (within
  ``max_dt_s + window`` periods), the one that sees the point closest to its optical
  axis (a fisheye's resolution and its calibration are best there), unless nearer laser
  points hide it in that frame (:func:`occlusion_depths`: a depth buffer of the laser
  points scanned around that frame's time, each splatted over the pixels its share of
  surface covers). A point hidden in every candidate is not coloured.

Points no frame sees (behind the camera, outside the image, too far in time, hidden)
keep ``coloured = False``. A frame of another size than the camera model's is not used
(:func:`odd_sized` finds them from their JPEG headers). Units: metres, host ns, pixels;
colours RGB uint8.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from concurrent.futures import Executor, Future
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from acq.camera import projection
from acq.camera.calibfile import CameraCalib
from acq.camera.camera_models import CameraModel
from acq.camera.jpeg import SharedDecodes, decode_jpeg_transient
from acq.camera.occlusion import occlusion_depths, visible
from acq.drivers.errors import ProtocolError
from acq.drivers.mjpeg import jpeg_size
from acq.geometry.transforms import PoseFn, Rigid, world_to_laser
from acq.time import sync

__all__ = [
    "VIEWS",
    "Coloured",
    "Colouring",
    "Crop",
    "Frame",
    "Options",
    "Pairs",
    "camera_poses",
    "crop_around",
    "odd_sized",
    "point_size",
    "start_colouring",
]


VIEWS = ("nearest", "best")


@dataclass(frozen=True)
class Options:
    """How points pick their frame (see the module docstring). ``cell_px``: the depth
    buffer's cell; ``margin_m`` + ``margin_rel`` x depth: how much nearer a laser point
    must be to hide another; ``context_s``: laser points within this of a frame's time
    go into its depth buffer. ``balance``: sample some points in a few more frames of
    each camera, for :mod:`acq.cloud.balance`; ``blend``: blend the cameras' colours
    (:mod:`acq.cloud.multiview`)."""

    view: str = "nearest"
    motion_compensation: bool = True
    max_dt_s: float = 0.1
    window: int = 3
    bilinear: bool = True
    cell_px: int = 2
    margin_m: float = 0.2
    margin_rel: float = 0.05
    context_s: float = 0.4
    balance: bool = True
    blend: bool = False

    def __post_init__(self) -> None:
        if self.view not in VIEWS:
            raise ValueError(f"view {self.view!r}: expected one of {', '.join(VIEWS)}")
        if self.window < 0 or self.max_dt_s <= 0 or self.cell_px < 1:
            raise ValueError("window >= 0, max_dt_s > 0 and cell_px >= 1 expected")


# with want_crops, each frame's pixels around the points it coloured are kept (a Crop), this
# many pixels beyond them: the facets of `acq mesh --texture` between those points and
# their neighbours are sampled there without decoding the frame again
CROP_MARGIN_PX = 32
PAIR_EVERY = 16  # one point in this many is also sampled in other frames, for balancing
PAIR_OFFSETS = (1, 8, 30)  # those frames: this many frames from the point's own


@dataclass(frozen=True)
class Pairs:
    """Points sampled again in other frames of the same camera, for
    :mod:`acq.cloud.balance`: ``point`` (K,) their indices, ``frame`` (K,) the other
    frame, ``rgb`` (K,3) uint8 the colour there, ``ok`` (K,) bool where it was seen."""

    point: np.ndarray
    frame: np.ndarray
    rgb: np.ndarray
    ok: np.ndarray

    @staticmethod
    def none() -> Pairs:
        empty = np.zeros(0, np.int64)
        return Pairs(empty, empty, np.zeros((0, 3), np.uint8), np.zeros(0, bool))


@dataclass(frozen=True)
class Coloured:
    """Per point: ``rgb`` (N,3) uint8, ``coloured`` (N,) bool, ``frame`` (N,) int64 the
    frame used (-1 none), ``dt_s`` (N,) float32 point time minus that frame's (NaN),
    ``theta`` (N,) float32 angle from that frame's optical axis, rad, and ``depth``
    (N,) float32 the point's distance from the camera then, m (NaN where not coloured);
    ``hidden`` (N,) bool: seen by a candidate frame but hidden in all (``best``); ``uv``
    (N,2) float32 the pixel in that frame (NaN; only when asked for); ``pairs``: points
    sampled again in other frames (:class:`Pairs`); ``failed`` (K,) int64 the frames that
    did not decode (indices into the frames given)."""

    rgb: np.ndarray
    coloured: np.ndarray
    frame: np.ndarray
    dt_s: np.ndarray
    theta: np.ndarray
    hidden: np.ndarray
    frames_used: int
    frames_failed: int
    uv: np.ndarray | None = None
    depth: np.ndarray | None = None
    pairs: Pairs = field(default_factory=Pairs.none)
    failed: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    crops: dict[int, Crop] = field(default_factory=dict)  # by frame (want_crops only)


Frame = bytes | np.ndarray  # a JPEG, or its image decoded (H,W,3) BGR uint8


@dataclass(frozen=True)
class Crop:
    """Part of a decoded frame: ``pixels`` (h,w,3) BGR uint8 whose first is the frame's
    pixel (``x0``, ``y0``); ``size`` (width, height) px: the whole frame's."""

    x0: int
    y0: int
    pixels: np.ndarray
    size: tuple[int, int]

    def holds(self, x0: int, y0: int, x1: int, y1: int) -> bool:
        """Whether the frame's pixels [x0, x1) x [y0, y1) are all in the crop."""
        h, w = self.pixels.shape[:2]
        return self.x0 <= x0 and self.y0 <= y0 and x1 <= self.x0 + w and y1 <= self.y0 + h


def crop_around(image: np.ndarray, uv: np.ndarray, margin: int = CROP_MARGIN_PX) -> Crop | None:
    """The part of ``image`` (H,W,3) around the pixels ``uv`` (N,2) px (NaN ignored),
    ``margin`` px beyond them (a copy); None when there are none."""
    ok = np.isfinite(uv).all(axis=1)
    if not ok.any():
        return None
    h, w = image.shape[:2]
    lo = np.floor(uv[ok].min(axis=0)).astype(int) - margin
    hi = np.ceil(uv[ok].max(axis=0)).astype(int) + margin + 1
    x0, y0 = max(0, int(lo[0])), max(0, int(lo[1]))
    x1, y1 = min(w, int(hi[0])), min(h, int(hi[1]))
    if x1 <= x0 or y1 <= y0:
        return None
    return Crop(x0, y0, image[y0:y1, x0:x1].copy(), (w, h))


def odd_sized(jpegs: Sequence[Frame], model: CameraModel) -> dict[int, tuple[int, int]]:
    """The frames of ``jpegs`` whose JPEG header (or decoded image) gives another size
    than ``model``'s: index -> (width, height) px (a header that does not parse is left
    to the decoder)."""
    want = (model.width, model.height)
    out: dict[int, tuple[int, int]] = {}
    for k, jpeg in enumerate(jpegs):
        if isinstance(jpeg, np.ndarray):
            size = (jpeg.shape[1], jpeg.shape[0])
        else:
            try:
                size = jpeg_size(jpeg)
            except ProtocolError:
                continue
        if size != want:
            out[k] = size
    return out


class _Rig:
    """Camera poses: ``laser_frame(P_world, t_ns)`` -> the laser frame as the rig stood
    at t (or the points as given without motion compensation)."""

    def __init__(self, cam: CameraCalib, laser_to_vehicle: Rigid, pose_at: PoseFn | None) -> None:
        self.cam, self.l2v, self.pose_at = cam, laser_to_vehicle, pose_at
        self.v2l = laser_to_vehicle.inverse()
        self._poses: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def prepare(self, t_ns: np.ndarray) -> None:
        """Look up the poses at ``t_ns`` (the frames' times) in one call."""
        if self.pose_at is not None and t_ns.size:
            R, t = self.pose_at(np.asarray(t_ns, dtype=np.int64))
            self._poses.update(zip(np.asarray(t_ns).tolist(), zip(R, t, strict=True), strict=True))

    def _pose(self, pose_at: PoseFn, t_ns: int) -> tuple[np.ndarray, np.ndarray]:
        pose = self._poses.get(t_ns)
        if pose is None:
            R, t = pose_at(np.array([t_ns], dtype=np.int64))
            pose = R[0], t[0]
        return pose

    def laser_frame(self, P_world: np.ndarray, t_ns: int) -> np.ndarray:
        if self.pose_at is None:
            return P_world
        R, t = self._pose(self.pose_at, t_ns)
        return world_to_laser(P_world, R, t, self.v2l)

    def camera_poses(self, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return camera_poses(self.cam, self.l2v, self.pose_at, t_ns)

    def camera(self, P_laser: np.ndarray) -> np.ndarray:
        return self.cam.camera_to_laser.inverse().apply(P_laser)


def camera_poses(
    cam: CameraCalib, laser_to_vehicle: Rigid, pose_at: PoseFn | None, t_ns: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The camera's rotations (M,3,3) and positions (M,3) m in the points' frame at
    ``t_ns`` (M,) (laser clock): the world as the rig stood then (``pose_at`` the
    vehicle's poses), or the laser frame without motion compensation (``pose_at`` None)."""
    c2l = cam.camera_to_laser
    if pose_at is None:
        return np.broadcast_to(c2l.rotation, (t_ns.size, 3, 3)), np.broadcast_to(
            c2l.translation, (t_ns.size, 3)
        )
    c2v = laser_to_vehicle @ c2l
    R, t = pose_at(np.asarray(t_ns, dtype=np.int64))
    return R @ c2v.rotation, np.einsum("nij,j->ni", R, c2v.translation) + t


def _theta(P_cam: np.ndarray) -> npt.NDArray[np.float64]:
    theta: npt.NDArray[np.float64] = np.arctan2(np.hypot(P_cam[:, 0], P_cam[:, 1]), P_cam[:, 2])
    return theta


class Colouring:
    """Points being coloured on a pool's threads (:func:`start_colouring`): every frame
    decoded once on a thread, its points sent back to where the rig stood and sampled
    there; :meth:`result` waits for them. The arrays are filled in place."""

    def __init__(
        self, P: np.ndarray, frame: np.ndarray, theta: np.ndarray, hidden: np.ndarray,
        time_ns: np.ndarray, frame_ns: np.ndarray, model: CameraModel, bilinear: bool,
        want_uv: bool, pair_point: np.ndarray | None = None,
        pair_frame: np.ndarray | None = None,
    ) -> None:  # fmt: skip
        n = P.shape[0]
        self.P = np.ascontiguousarray(P, dtype=np.float64)
        self.bgr = np.zeros((n, 3), dtype=np.uint8)
        self.coloured = np.zeros(n, dtype=bool)
        self.uv = np.full((n, 2), np.nan, dtype=np.float32) if want_uv else None
        self.depth = np.full(n, np.nan, dtype=np.float32)
        self.frame, self.theta, self.hidden = frame, theta, hidden
        self.time_ns, self.frame_ns = time_ns, frame_ns
        self.model, self.bilinear = model, bilinear
        self.futures: list[Future[bool]] = []
        self.future_frames: list[int] = []  # the frame each future colours from
        self.frame_map: np.ndarray | None = None  # frame indices of a subset -> the caller's
        self.pair_point = np.zeros(0, np.int64) if pair_point is None else pair_point
        self.pair_frame = np.zeros(0, np.int64) if pair_frame is None else pair_frame
        self.pair_P = np.ascontiguousarray(self.P[self.pair_point])
        self.pair_bgr = np.zeros((self.pair_point.size, 3), dtype=np.uint8)
        self.pair_ok = np.zeros(self.pair_point.size, dtype=bool)
        self.crops: dict[int, Crop] = {}  # with want_crops: by frame, around its points

    def colour_frame(
        self, jpeg: Frame, idx: np.ndarray, R: np.ndarray, t: np.ndarray,
        pairs: np.ndarray | None = None, frame: int | None = None,
    ) -> bool:  # fmt: skip
        """Decode one frame (unless given decoded) and colour its points ``idx`` (the
        camera at rotation ``R`` and position ``t`` in the points' frame) and its
        ``pairs`` (indices into the pair arrays); False when it does not decode or is not
        of the camera model's size. ``frame``: its index, to keep its crop under (with
        want_crops)."""
        image = jpeg if isinstance(jpeg, np.ndarray) else decode_jpeg_transient(jpeg)
        return self.colour_image(image, idx, R, t, pairs, frame)

    def colour_image(
        self, image: np.ndarray | None, idx: np.ndarray, R: np.ndarray, t: np.ndarray,
        pairs: np.ndarray | None = None, frame: int | None = None,
    ) -> bool:  # fmt: skip
        """:meth:`colour_frame` with the frame decoded already (None: it did not)."""
        if image is None or image.shape[:2] != (self.model.height, self.model.width):
            return False
        projection.colour_into(
            self.P, idx, self.model, (R, t), image, self.bgr, self.coloured, self.uv,
            bilinear=self.bilinear,
        )  # fmt: skip
        projection.depth_and_angle(self.P, idx, (R, t), self.depth, self.theta)
        if self.uv is not None and frame is not None:
            crop = crop_around(image, self.uv[idx])
            if crop is not None:
                self.crops[frame] = crop
        if pairs is not None and pairs.size:
            projection.colour_into(
                self.pair_P, pairs, self.model, (R, t), image, self.pair_bgr, self.pair_ok,
                bilinear=self.bilinear,
            )  # fmt: skip
        return True

    def result(self) -> Coloured:
        """Wait for every frame; the points' colours (see :class:`Coloured`)."""
        done = [f.result() for f in self.futures]
        used_n, failed = sum(done), len(done) - sum(done)
        bad = np.array(
            [j for j, ok in zip(self.future_frames, done, strict=True) if not ok], np.int64
        )
        coloured = self.coloured
        frame = np.where(coloured, self.frame, -1)
        if self.frame_ns.size:
            dt = np.where(
                coloured, (self.time_ns - self.frame_ns[np.maximum(frame, 0)]) * 1e-9, np.nan
            )
        else:  # no frame (a camera without one near these points): nothing coloured
            dt = np.full(self.time_ns.shape, np.nan)
        theta = np.where(coloured, self.theta, np.nan).astype(np.float32)
        depth = np.where(coloured, self.depth, np.nan).astype(np.float32)
        pair_frame = self.pair_frame
        crops = self.crops
        if self.frame_map is not None and self.frame_map.size:
            frame = np.where(frame >= 0, self.frame_map[np.maximum(frame, 0)], -1)
            pair_frame = self.frame_map[pair_frame]
            bad = self.frame_map[bad]
            crops = {int(self.frame_map[j]): c for j, c in crops.items()}
        pairs = Pairs(self.pair_point, pair_frame, self.pair_bgr[:, ::-1], self.pair_ok)
        return Coloured(
            self.bgr[:, ::-1], coloured, frame, dt.astype(np.float32), theta, self.hidden,
            used_n, failed, self.uv, depth, pairs, bad, crops,
        )  # fmt: skip


def start_colouring(
    P: np.ndarray,
    time_ns: np.ndarray,
    size_m: np.ndarray,
    frame_ns: np.ndarray,
    jpegs: Sequence[Frame],
    cam: CameraCalib,
    laser_to_vehicle: Rigid,
    pose_at: PoseFn | None,
    options: Options | None = None,
    *,
    pool: Executor,
    want_uv: bool = False,
    frame_ok: np.ndarray | None = None,
    need: np.ndarray | None = None,
    want_crops: bool = False,
    decodes: SharedDecodes | None = None,
) -> Colouring:
    """Colour points ``P`` (N,3) m measured at ``time_ns`` (N,) host ns, sorted by time:
    in the world when ``pose_at`` is given and motion is compensated, else in the laser
    frame at their own time. ``frame_ns`` (M,) the frames' mid-exposure times on the
    laser's clock (the calibration's time offset already applied), ``jpegs`` their
    bytes (or their images, decoded); ``size_m`` (N,) each point's share of surface
    (for the depth buffers);
    ``frame_ok`` (M,) bool: frames that may be used (e.g. those the trajectory covers);
    ``need`` (N,) bool: the points to colour (default all; the others only hide points
    in ``best``'s depth buffers); ``want_uv``: each point's pixel; with it,
    ``want_crops``: each frame's part around its points' pixels (:class:`Crop`,
    :data:`CROP_MARGIN_PX` beyond them). ``decodes``: the frames given as JPEG go
    there instead (on its pool), a frame decoded once for every colouring that asks for
    it while it waits (known by the camera's name and ``frame_ns``).

    The frames go on ``pool`` (first come, first served), one task each, and are not
    waited for: the caller goes on (placing the next points, writing the last ones)
    while they decode; :meth:`Colouring.result` waits."""
    options = options or Options()
    n = P.shape[0]
    rig = _Rig(cam, laser_to_vehicle, pose_at if options.motion_compensation else None)
    if options.view == "best" and rig.pose_at is None:
        raise ValueError("--view best needs a trajectory (and motion compensation)")
    if frame_ok is not None and not frame_ok.all():
        keep = np.flatnonzero(frame_ok)
        sub = start_colouring(
            P, time_ns, size_m, frame_ns[keep], [jpegs[int(k)] for k in keep], cam,
            laser_to_vehicle, pose_at, options, pool=pool, want_uv=want_uv, need=need,
            want_crops=want_crops, decodes=decodes,
        )  # fmt: skip
        sub.frame_map = keep
        return sub
    frame = np.full(n, -1, dtype=np.int64)
    theta = np.full(n, np.nan, dtype=np.float32)
    hidden = np.zeros(n, dtype=bool)
    if n == 0 or frame_ns.size == 0:
        return Colouring(P, frame, theta, hidden, time_ns, frame_ns, cam.model, True, want_uv)
    need = np.ones(n, dtype=bool) if need is None else need
    pairing = sync.pair_frames(time_ns, frame_ns)
    near = np.where(np.abs(pairing.dt_s) <= options.max_dt_s, pairing.nearest, -1)
    if options.view == "nearest":
        frame = np.where(need, near, -1)
    else:
        rig.prepare(frame_ns)
        frame, theta, hidden = _best(P, time_ns, size_m, frame_ns, near, rig, options, need)
    pair_point, pair_frame = (
        _pairs(frame, frame_ns) if options.balance and rig.pose_at is not None else (None, None)
    )
    out = Colouring(
        P, frame, theta, hidden, time_ns, frame_ns, cam.model, options.bilinear, want_uv,
        pair_point, pair_frame,
    )  # fmt: skip
    points, again = _by_frame(frame), _by_frame(out.pair_frame)
    frames = np.array(sorted(points.keys() | again.keys()), dtype=np.int64)
    Rs, ts = rig.camera_poses(frame_ns[frames])
    none = np.zeros(0, np.int64)
    for k, j in enumerate(frames.tolist()):
        args = (
            points.get(j, none),
            Rs[k],
            ts[k],
            again.get(j),
            j if want_uv and want_crops else None,
        )
        jpeg = jpegs[j]
        if decodes is not None and isinstance(jpeg, bytes):
            task = decodes.submit(
                (cam.name, int(frame_ns[j])), jpeg, functools.partial(_colour_image, out, args)
            )
        else:
            task = pool.submit(out.colour_frame, jpeg, *args)
        out.futures.append(task)
        out.future_frames.append(j)
    return out


def _colour_image(out: Colouring, args: tuple[Any, ...], image: np.ndarray | None) -> bool:
    return out.colour_image(image, *args)


def _by_frame(frame: np.ndarray) -> dict[int, np.ndarray]:
    """The indices of ``frame`` (K,) by their value (frames >= 0 only), each ascending."""
    if frame.size == 0:
        return {}
    order, starts = _group(np.asarray(frame, dtype=np.int64), max(int(frame.max()) + 1, 0))
    used = np.flatnonzero(starts[1:] > starts[:-1])
    return {j: order[starts[j] : starts[j + 1]] for j in used.tolist()}


@numba.njit(nogil=True, cache=True, error_model="numpy")
def _group(frame, m):  # type: ignore[no-untyped-def]
    """(order, starts): the indices of ``frame``'s values in [0, ``m``) grouped by value,
    ascending within a group (a counting sort: as a stable argsort, in one pass); value
    j's are ``order[starts[j]:starts[j + 1]]``."""
    starts = np.zeros(m + 1, dtype=np.int64)
    for f in frame:
        if f >= 0:
            starts[f + 1] += 1
    for j in range(m):
        starts[j + 1] += starts[j]
    at = starts[:m].copy()
    order = np.empty(starts[m], dtype=np.int64)
    for i in range(frame.size):
        f = frame[i]
        if f >= 0:
            order[at[f]] = i
            at[f] += 1
    return order, starts


def _pairs(frame: np.ndarray, frame_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(points, other frames): one point in ``PAIR_EVERY`` of those with a ``frame``,
    each paired with the frames ``PAIR_OFFSETS`` away from its own in time order (after
    it for every other point, before it for the rest), where there is one."""
    sub = np.flatnonzero(frame >= 0)[::PAIR_EVERY]
    if sub.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    order_f = np.argsort(frame_ns, kind="stable")
    rank = np.empty_like(order_f)
    rank[order_f] = np.arange(order_f.size)
    sign = np.where(np.arange(sub.size) % 2 == 0, 1, -1)
    points, frames = [], []
    for offset in PAIR_OFFSETS:
        r = rank[frame[sub]] + sign * offset
        ok = (r >= 0) & (r < order_f.size)
        points.append(sub[ok])
        frames.append(order_f[r[ok]])
    return np.concatenate(points), np.concatenate(frames)


def _best(
    P: np.ndarray,
    time_ns: np.ndarray,
    size_m: np.ndarray,
    frame_ns: np.ndarray,
    near: np.ndarray,
    rig: _Rig,
    options: Options,
    need: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(frame, theta, hidden) per point for ``view="best"`` (module docstring), for the
    points ``need``."""
    n, W = P.shape[0], options.window
    model = rig.cam.model
    f_px = 0.5 * (model.fx + model.fy)
    best = np.full(n, -1, dtype=np.int64)
    best_theta = np.full(n, np.inf, dtype=np.float32)
    candidate = np.zeros(n, dtype=bool)
    order_f = np.argsort(frame_ns, kind="stable")
    rank = np.empty_like(order_f)
    rank[order_f] = np.arange(order_f.size)
    near_rank = np.where(near >= 0, rank[np.maximum(near, 0)], -(10**9))
    period = float(np.median(np.diff(frame_ns[order_f]))) * 1e-9 if frame_ns.size > 1 else 0.04
    max_dt = options.max_dt_s + W * period
    ctx = round(options.context_s * 1e9)
    for r, j in enumerate(order_f.tolist()):
        t_f = int(frame_ns[j])
        lo, hi = np.searchsorted(time_ns, [t_f - max_dt * 1e9, t_f + max_dt * 1e9])
        idx = np.arange(lo, hi)
        idx = idx[(np.abs(near_rank[idx] - r) <= W) & need[idx]]
        if idx.size == 0:
            continue
        # the depth buffer of the laser points around this frame's time
        c_lo, c_hi = np.searchsorted(time_ns, [t_f - ctx, t_f + ctx])
        ctx_idx = np.arange(c_lo, c_hi)
        P_c = rig.camera(rig.laser_frame(P[ctx_idx], t_f))
        uv_c, ok_c = projection.project(P_c, model, Rigid.identity())
        depth_c = np.linalg.norm(P_c, axis=1)
        zbuf = occlusion_depths(
            uv_c[ok_c], depth_c[ok_c], size_m[ctx_idx][ok_c], f_px,
            (model.height, model.width), options.cell_px,
        )  # fmt: skip
        P_p = rig.camera(rig.laser_frame(P[idx], t_f))
        uv, ok = projection.project(P_p, model, Rigid.identity())
        candidate[idx[ok]] = True
        depth = np.linalg.norm(P_p, axis=1)
        seen = ok & visible(zbuf, uv, depth, options.cell_px, options.margin_m, options.margin_rel)
        th = _theta(P_p).astype(np.float32)
        better = seen & (th < best_theta[idx])
        best[idx[better]] = j
        best_theta[idx[better]] = th[better]
    hidden = candidate & (best < 0)
    theta = np.where(best >= 0, best_theta, np.nan).astype(np.float32)
    return best, theta, hidden


def point_size(
    ranges: np.ndarray, angle_increment: float, travel_m: float
) -> npt.NDArray[np.float32]:
    """Each point's share of surface, m: the larger of its spacing along the scan
    (range x angle step) and the rig's travel between scans."""
    size: np.ndarray = np.maximum(np.abs(ranges) * abs(angle_increment), travel_m)
    return size.astype(np.float32)
