"""Whether a camera's calibration still holds on a drive (``acq calibrate check``): the
pose (``camera_to_laser``) and time offset that best align the drive's swath with the
camera's frames (:mod:`acq.calib.pose_search`), their standard errors from disjoint
blocks of consecutive frames, and the verdict.

The swath: every chosen frame (:mod:`acq.calib.drive_frames`: the rig moving, spread
over the drive) sees the laser points measured within ``window_s`` of its time, placed
in the world with the trajectory (a 2D scanner's single line would cross each image
once; the swath around it covers the walls and road the camera sees), those within
``max_range_m`` of the camera and inside the image at CALIB's pose, thinned to
``points_per_frame``. The measure is the return strengths' mutual information with
the grey levels (:mod:`acq.calib.information`; the depth-edge term is there, weighed
``edge_weight``, 0 by default: it saw nothing on the simulated street), the images
blurred by ``blur_px``: a little against noise, no more, since a wider blur flattens
the measure along each camera's optical axis, the direction the images pin down
least, and its top then slides (1 px put the cameras 13 mm behind where they are on
average, 0.5 px 4 mm: ``bench/calib_check.py --blur``).

The verdict, per group of parameters (rotation, translation, time offset): the change
from CALIB over its standard error (the estimate's and, when calib.yaml has one, the
calibration's, added in quadrature; each at least a floor: a spread of a few blocks can
come out small by chance), summed in squares, against the chi-square quantile of
0.999 (3 degrees of freedom, 1 for the time offset). Above it in any group:
"moved"; else "holds" when the standard errors are small enough to say so
(``max_std``), else "cannot tell". It cannot tell either, with the reason, without
return strengths, motion, frames or points in view.

Angles in degrees, lengths in mm, times in ms in what it reports; rad, m, s inside.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from acq.calib.drive_frames import moving_frames, points_near
from acq.calib.information import bins_of_bytes, depth_edges, image_features, quantile_bins
from acq.calib.pose_search import (
    FIT_STEPS,
    PARAMS,
    START_STEPS,
    Many,
    Scorer,
    Swath,
    gradient,
    newton,
    search,
    shifted,
)
from acq.camera import projection
from acq.camera.calibfile import CameraCalib
from acq.camera.jpeg import decoded_frames
from acq.geometry.transforms import PoseFn, Rigid, world_to_laser
from acq.time import sync

__all__ = ["CheckOptions", "PoseCheck", "check_frames", "check_pose", "pixels_at"]

# chi-square quantiles at 1 - 1e-3 for 3 and 1 degrees of freedom
_CHI2 = {3: 16.266, 1: 10.828}
_FLOOR = np.array([np.radians(0.05)] * 3 + [0.005] * 3 + [0.001])  # rad, m, s


@dataclass(frozen=True)
class CheckOptions:
    """The check's settings (module docstring); times s, lengths m, angles rad."""

    max_frames: int = 80
    window_s: float = 1.0
    points_per_frame: int = 2500
    max_range_m: float = 20.0
    margin_px: float = 8.0
    min_speed_mps: float = 1.0
    blur_px: float = 0.5
    bins: int = 24
    edge_weight: float = 0.0
    rounds: int = 2
    search_every: int = 2
    newton_steps: int = 3
    blocks: int = 8
    time_offset: bool = True
    max_std: tuple[float, float, float] = (np.radians(0.25), 0.025, 0.003)
    threads: int = 2


@dataclass(frozen=True)
class PoseCheck:
    """The check of one camera: ``verdict`` "holds", "moved" or "cannot tell" (with
    ``reason``); the estimate's change from CALIB ``change`` (7,) and its standard error
    ``std`` (7,) (:data:`acq.calib.pose_search.PARAMS`: rad, m, s); the estimate itself,
    ``camera_to_laser`` and ``time_offset_s``; ``blocks`` each block's change (K,7);
    ``px_at_10m`` how far a point 10 m away moves in the image between CALIB's pose and
    the estimate (median over the image, px); ``frames``, ``points`` used; ``score``
    the measure at the estimate and at CALIB (nats); ``evaluations`` of the measure."""

    verdict: str
    reason: str = ""
    change: np.ndarray = field(default_factory=lambda: np.full(7, np.nan))
    std: np.ndarray = field(default_factory=lambda: np.full(7, np.nan))
    camera_to_laser: Rigid | None = None
    time_offset_s: float = float("nan")
    blocks: np.ndarray = field(default_factory=lambda: np.zeros((0, 7)))
    px_at_10m: float = float("nan")
    frames: int = 0
    points: int = 0
    score: tuple[float, float] = (float("nan"), float("nan"))
    evaluations: int = 0

    @property
    def found(self) -> bool:
        """Whether there is an estimate (holds or moved)."""
        return self.camera_to_laser is not None

    @property
    def angle_deg(self) -> float:
        """The estimate's rotation from CALIB, degrees."""
        return float(np.degrees(np.linalg.norm(self.change[:3])))

    @property
    def shift_mm(self) -> float:
        """The estimate's translation from CALIB, mm."""
        return float(1e3 * np.linalg.norm(self.change[3:6]))

    @property
    def offset_ms(self) -> float:
        """The estimate's time offset minus CALIB's, ms."""
        return float(1e3 * self.change[6])

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: degrees, mm, ms."""
        scale = np.array([np.degrees(1.0)] * 3 + [1e3] * 3 + [1e3])

        def axes(v: np.ndarray) -> dict[str, float | None]:
            return {p: (None if not np.isfinite(x) else round(float(x), 4))
                    for p, x in zip(PARAMS, v * scale, strict=True)}  # fmt: skip

        d: dict[str, Any] = {"verdict": self.verdict, "reason": self.reason}
        if self.found:
            assert self.camera_to_laser is not None
            d |= {
                "rotation_deg": round(self.angle_deg, 4),
                "translation_mm": round(self.shift_mm, 2),
                "time_offset_ms": round(self.offset_ms, 3),
                "px_at_10m": round(self.px_at_10m, 2),
                "change": axes(self.change),
                "std": axes(self.std),
                "blocks": [axes(b) for b in self.blocks],
                "camera_to_laser": self.camera_to_laser.to_dict(),
                "time_offset_s": self.time_offset_s,
                "score_nats": {"estimate": self.score[0], "calib": self.score[1]},
            }
        d |= {"frames": self.frames, "points": self.points, "evaluations": self.evaluations}
        return d

    def summary(self, name: str) -> dict[str, Any]:
        """:meth:`to_dict` with camera ``name``'s verdict :meth:`line` (``line``)."""
        return {"line": self.line(name), **self.to_dict()}

    def line(self, name: str) -> str:
        """The one line that says camera ``name``'s verdict."""
        if not self.found or self.verdict == "cannot tell":
            return f"camera {name}: cannot tell: {self.reason}"
        s = self.std
        errs = (
            f"standard errors {np.degrees(np.linalg.norm(s[:3])):.2f} deg, "
            f"{1e3 * np.linalg.norm(s[3:6]):.1f} mm, {1e3 * s[6]:.2f} ms"
        )
        size = (
            f"{self.angle_deg:.2f} deg and {self.shift_mm:.1f} mm and {self.offset_ms:+.2f} ms, "
            f"{self.px_at_10m:.1f} px at 10 m"
        )
        used = f"from {self.frames} frames, {self.points:,} laser points"
        if self.verdict == "moved":
            return f"camera {name}: moved by {size} ({self.reason}; {errs}), {used}"
        return f"camera {name}: the calibration holds: within {size} of CALIB ({errs}), {used}"


def pixels_at(cam: CameraCalib, moved: Rigid, distance_m: float = 10.0) -> float:
    """How far (px) points ``distance_m`` away move in ``cam``'s image when its pose goes
    from CALIB's to ``moved``: the median over a grid of the image's pixels."""
    model = cam.model
    u, v = np.meshgrid(np.linspace(0, model.width - 1, 24), np.linspace(0, model.height - 1, 18))
    uv = np.stack([u.ravel(), v.ravel()], axis=1)
    rays = model.unproject(uv)
    keep = np.isfinite(rays).all(axis=1) & (rays[:, 2] > 0.05)
    P_laser = cam.camera_to_laser.apply(distance_m * rays[keep])
    a, ok_a = projection.project(P_laser, model, cam.camera_to_laser)
    b, ok_b = projection.project(P_laser, model, moved)
    ok = ok_a & ok_b
    return float(np.median(np.linalg.norm(a[ok] - b[ok], axis=1))) if ok.any() else float("nan")


def check_frames(
    frame_ns: np.ndarray, cam: CameraCalib, pose_at: PoseFn,
    covers: Callable[[np.ndarray], np.ndarray], opt: CheckOptions,
) -> np.ndarray:  # fmt: skip
    """Indices of the frames, re-timed at ``frame_ns`` (M,) ns (no offset applied), that
    the check of camera ``cam`` (:func:`check_pose`, options ``opt``) uses on a drive
    posed by ``pose_at``/``covers``: known before the images are read."""
    t_laser = sync.on_laser_clock(frame_ns, round(cam.time_offset_s * 1e9))
    return moving_frames(
        t_laser, pose_at, covers, min_speed_mps=opt.min_speed_mps, max_frames=opt.max_frames
    )


def _swath(
    P_world: np.ndarray, time_ns: np.ndarray, strength: np.ndarray, edge: np.ndarray,
    frame_ns: np.ndarray, jpegs: list[bytes], cam: CameraCalib, laser_to_vehicle: Rigid,
    pose_at: PoseFn, covers: Callable[[np.ndarray], np.ndarray], opt: CheckOptions,
) -> Swath | str:  # fmt: skip
    """The swath the search scores (module docstring), or why there is none."""
    usable = np.isfinite(P_world).all(axis=1) & (strength > 0)
    if not usable.any():
        return "no laser return strengths in the log (SCIP ME / CoLa RSSI1 needed)"
    t_laser = sync.on_laser_clock(frame_ns, round(cam.time_offset_s * 1e9))
    pick = check_frames(frame_ns, cam, pose_at, covers, opt)
    if pick.size == 0:
        return "the rig does not move (or no pose) while the camera records"
    # thinned first: most of a window's points are out of view or too far
    near = points_near(time_ns, usable, t_laser[pick], opt.window_s * 1e9, 4 * opt.points_per_frame)
    model, c2l, v2l = cam.model, cam.camera_to_laser, laser_to_vehicle.inverse()
    R, tr = pose_at(t_laser[pick])
    m = opt.margin_px
    kept: list[tuple[int, np.ndarray]] = []
    for r, (j, idx) in enumerate(zip(pick.tolist(), near, strict=True)):
        if idx.size == 0:
            continue
        P_l = world_to_laser(P_world[idx], R[r], tr[r], v2l)
        uv, ok = projection.project(P_l, model, c2l)
        dist = np.linalg.norm(P_l - c2l.translation, axis=1)
        ok &= (dist < opt.max_range_m) & (uv[:, 0] >= m) & (uv[:, 0] <= model.width - 1 - m)
        ok &= (uv[:, 1] >= m) & (uv[:, 1] <= model.height - 1 - m)
        idx, uv = idx[ok], uv[ok]
        if idx.size > opt.points_per_frame:
            keep = np.linspace(0, idx.size - 1, opt.points_per_frame).astype(np.int64)
            idx, uv = idx[keep], uv[keep]
        # in the order of their pixels' rows: the search samples the images in passes
        # that then read memory nearly in order
        idx = idx[np.argsort(np.rint(uv[:, 1]) * model.width + uv[:, 0], kind="stable")]
        if idx.size:
            kept.append((j, idx))
    features: list[np.ndarray] = []
    frames: list[tuple[int, np.ndarray]] = []
    order = np.array([j for j, _ in kept], dtype=np.int64)
    for (j, idx), image in zip(kept, decoded_frames(jpegs, order, opt.threads), strict=True):
        if image is None or image.shape[:2] != (model.height, model.width):
            continue
        # the gradient left out when its term weighs nothing: half the memory the
        # search reads for every point
        features.append(image_features(image, opt.blur_px, gradient=opt.edge_weight > 0))
        frames.append((j, idx))
    if not frames:
        return "no laser points in view of the frames"
    pts = np.concatenate([idx for _, idx in frames])
    if pts.size < 2000:
        return f"only {pts.size} laser points in view of the frames"
    starts = np.concatenate([[0], np.cumsum([idx.size for _, idx in frames])]).astype(np.int64)
    s_bins = quantile_bins(strength[pts], opt.bins)
    unbinned = np.zeros((len(frames), 256), np.int64)  # until the grey levels' bins are made
    swath = Swath(
        P_world[pts], starts, frame_ns[[j for j, _ in frames]], np.stack(features), s_bins,
        edge[pts], unbinned, unbinned, opt.bins,
        opt.edge_weight,
    )  # fmt: skip
    return swath


def check_pose(
    P_world: np.ndarray, time_ns: np.ndarray, strength: np.ndarray, scan: np.ndarray,
    step: np.ndarray, r: np.ndarray, frame_ns: np.ndarray, jpegs: list[bytes],
    cam: CameraCalib, laser_to_vehicle: Rigid, pose_at: PoseFn,
    covers: Callable[[np.ndarray], np.ndarray], options: CheckOptions | None = None,
) -> PoseCheck:  # fmt: skip
    """Check camera ``cam`` (CALIB's) on a drive (module docstring): laser points
    ``P_world`` (N,3) m placed in the world, in time order, measured at ``time_ns`` (N,)
    with return strengths ``strength``, from beams ``step`` of scans ``scan`` at ranges
    ``r`` m; the camera's frames stamped ``frame_ns`` (M,) (re-timed, no offset applied)
    with their ``jpegs``; the rig's pose from ``pose_at``/``covers``."""
    opt = options or CheckOptions()
    edge = depth_edges(scan, step, r)
    made = _swath(P_world, time_ns, strength, edge, frame_ns, jpegs, cam, laser_to_vehicle,
                  pose_at, covers, opt)  # fmt: skip
    if isinstance(made, str):
        return PoseCheck("cannot tell", made)
    # the images' bins fixed at CALIB's pose, so that every candidate's score compares
    plain = Scorer(made, cam.model, cam.camera_to_laser, cam.time_offset_s, laser_to_vehicle,
                   pose_at)  # fmt: skip
    sampled, ok = plain.samples(np.zeros(7))
    luts = [np.zeros((made.frames, 256), np.int64)] * 2
    for c in range(sampled.shape[1]):
        luts[c] = np.stack([
            bins_of_bytes(sampled[a:b, c][ok[a:b]], opt.bins)
            for a, b in itertools.pairwise(made.starts.tolist())
        ])  # fmt: skip
    swath = replace(made, grey_lut=luts[0], grad_lut=luts[1])
    score = Scorer(swath, cam.model, cam.camera_to_laser, cam.time_offset_s, laser_to_vehicle,
                   pose_at)  # fmt: skip
    free = np.ones(7, dtype=bool)
    free[6] = opt.time_offset
    # the search only finds the top's neighbourhood: on part of the points
    coarse = Scorer(swath.every(opt.search_every), cam.model, cam.camera_to_laser,
                    cam.time_offset_s, laser_to_vehicle, pose_at)  # fmt: skip
    x = search(coarse.many, np.zeros(7), START_STEPS, opt.rounds, free)

    def on(f: Scorer) -> Many:
        """``f`` of candidates of the free parameters (K,n), the others at the estimate's."""

        def g(Z: np.ndarray) -> np.ndarray:
            Y = np.repeat(x[None], len(Z), axis=0)
            Y[:, free] = Z
            return f.many(Y)

        return g

    h = FIT_STEPS[free]
    z, H = newton(on(score), x[free], h, opt.newton_steps)
    x[free] = z
    # the blocks: disjoint runs of consecutive frames, each its own estimate
    k = max(2, min(opt.blocks, swath.frames // 4))
    cuts = np.linspace(0, swath.frames, k + 1).astype(int)
    blocks = []
    evaluations = coarse.evaluations + score.evaluations
    for lo, hi in itertools.pairwise(cuts.tolist()):
        part = Scorer(swath.part(int(lo), int(hi)), cam.model, cam.camera_to_laser,
                      cam.time_offset_s, laser_to_vehicle, pose_at)  # fmt: skip
        est = np.full(7, np.nan)
        est[free] = z - np.linalg.solve(H, gradient(on(part), z, h)) * h
        blocks.append(est)
        evaluations += part.evaluations
    b = np.array(blocks)
    std = b.std(axis=0, ddof=1) / np.sqrt(len(blocks))
    moved_pose = shifted(cam.camera_to_laser, x)
    result = PoseCheck(
        verdict="", change=x, std=std, camera_to_laser=moved_pose,
        time_offset_s=cam.time_offset_s + float(x[6]), blocks=b,
        px_at_10m=pixels_at(cam, moved_pose), frames=swath.frames, points=swath.points,
        score=(score(x), score(np.zeros(7))), evaluations=evaluations + 2,
    )  # fmt: skip
    verdict, reason = _verdict(x, std, cam, opt)
    return replace(result, verdict=verdict, reason=reason)


def _verdict(
    x: np.ndarray, std: np.ndarray, cam: CameraCalib, opt: CheckOptions
) -> tuple[str, str]:
    """The verdict ("holds", "moved" or "cannot tell") and why (module docstring)."""
    prior = np.zeros(7)
    if cam.std.rotation_deg is not None:
        prior[:3] = np.radians(cam.std.rotation_deg)
    if cam.std.translation_m is not None:
        prior[3:6] = cam.std.translation_m
    if cam.std.time_offset_s is not None:
        prior[6] = cam.std.time_offset_s
    sigma = np.maximum(np.hypot(std, prior), _FLOOR)
    z2 = (x / sigma) ** 2
    groups = {"rotation": slice(0, 3), "translation": slice(3, 6), "time offset": slice(6, 7)}
    beyond = [g for g, s in groups.items() if z2[s].sum() > _CHI2[s.stop - s.start]]
    if beyond:
        return "moved", f"{' and '.join(beyond)} beyond the uncertainty"
    worst = [
        f"{g} {v}" for g, v, lim in (
            ("rotation", f"{np.degrees(np.linalg.norm(std[:3])):.2f} deg", opt.max_std[0]),
            ("translation", f"{1e3 * np.linalg.norm(std[3:6]):.0f} mm", opt.max_std[1]),
            ("time offset", f"{1e3 * std[6]:.1f} ms", opt.max_std[2]),
        ) if np.linalg.norm(std[groups[g]]) > lim
    ]  # fmt: skip
    if worst:
        return "cannot tell", (
            f"the drive pins the pose down too loosely (standard errors: {', '.join(worst)}); "
            "it needs more motion, texture or return strength"
        )
    return "holds", ""
