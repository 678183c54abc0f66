"""Accuracy of the camera–laser calibration (issue 7, paper §3.2) on simulated boards.

Data: ``acq.sim.board_poses.simulate`` — a 1 m board (9 x 7 corners of 0.1 m) 1–4 m from the
rig, tilted up to ±30 degrees about each axis, seen by the 185-degree fisheye of
``acq.sim.world.default_rig`` (corners with 0.2 px noise, plane by PnP) and cut by the scan
plane (0.25 degree steps, 10 mm range noise). One JSON line per result:

- ``poses20``: over ``--seeds`` seeds with 20 poses, the geodesic rotation error (deg) and
  the translation error (mm), median and 95th percentile, for the linear solution, the
  refinement with the planes taken as exact (``plane_errors=False``, the brief's
  point-to-plane LM) and the default (plane errors modelled); ``std_ratio`` is the mean
  reported std over the RMS error per parameter (1 = the covariance is honest).
- ``vs_poses``: the same errors for 5, 8, 10, 15, 20, 30 poses (the first n of 30).
- ``outliers``: 2 of 20 boards moved between image and scan: detected, missed, good
  poses dropped, and the errors.
- ``near``: boards at 1–2 m instead of 1–4 m (20 poses): what the geometry buys.
- ``regular_lens``: the paper's way — a regular lens (pinhole, f = 600 px) on the camera
  for this calibration, boards at 1.5–4 m within ±20 degrees of its axis.
- ``cramer_rao``: the Cramér–Rao bound of the 20-pose problem (corners and ranges with
  the simulated noise, every board pose unknown): the median error an efficient unbiased
  estimator would reach, from the bound's covariance of each seed (``samples`` draws per
  seed), and ``efficiency`` = our median / the bound's median (1 = nothing left to gain
  from the same data).
- ``still_pose``: 20 poses, each held still for a while: corners averaged over
  ``frames`` frames and ranges the per-beam median of ``scans`` scans (what
  ``acq calibrate extrinsic`` does with a log), as the image and range noise average out.
- ``targets``: median rotation <= 0.1 deg and translation <= 5 mm with 20 poses.
- ``rig_two_cameras`` (``--rig``, alone): the two-camera rig (``default_rig(cameras=2)``),
  one simulated board recording (``acq.sim.board_log``, ``--rig-poses`` poses a camera
  held 1.5 s) calibrated by ``acq calibrate extrinsic`` for both cameras in one call:
  each camera's rotation (deg) and translation (mm) error against its truth, and the
  relative pose left -> right's error against the rig's, beside the spread the two
  calibrations' std predict for it; wall time of the call.

Run as a script: ``python bench/extrinsic.py [--seeds N]`` or
``--rig [--rig-poses N] [--rig-seed S]``.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import json
import math
import tempfile
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from acq.calib import extrinsic as ex
from acq.calib import relative_pose
from acq.calib.board_pose import BoardPose
from acq.calib.extrinsic_linear import linear_solution
from acq.camera import calibfile
from acq.camera.camera_models import Pinhole
from acq.cli import main as acq_main
from acq.geometry.rotations import matrix_from_rotvec, rotvec_from_matrix
from acq.geometry.transforms import Rigid
from acq.sim.board_log import write_board_log
from acq.sim.board_poses import BoardData, simulate
from acq.sim.world import default_rig

POSE_COUNTS = (5, 8, 10, 15, 20, 30)
STILL = ((1, 1), (4, 6), (10, 16), (25, 40))  # (frames, scans) per pose: 1 s = 25 and 40


def cramer_rao(data: BoardData, pixel_noise: float = 0.2, range_noise: float = 0.01) -> np.ndarray:
    """(6,6) Cramér–Rao bound of camera_to_laser (left rotation vector about the laser
    axes, rad; translation, m) for ``data``'s poses: the inverse Fisher information of
    every corner (``pixel_noise`` px per axis) and every range (``range_noise`` m along
    its beam), with each board's pose a nuisance parameter (Schur complement)."""
    E, obj, lens = data.truth, data.board.corners(), data.lens
    n = len(data.poses)
    info = np.zeros((6 + 6 * n, 6 + 6 * n))

    def moved(T: Rigid, x: np.ndarray) -> Rigid:
        return Rigid(matrix_from_rotvec(x[:3]) @ T.rotation, T.translation + x[3:])

    for i, (board, pose) in enumerate(zip(data.boards, data.poses, strict=True)):
        B = E.inverse() @ board  # board_to_camera
        beams = pose.points / np.linalg.norm(pose.points, axis=1, keepdims=True)

        def measure(x: np.ndarray, B: Rigid = B, beams: np.ndarray = beams) -> np.ndarray:
            Bx = moved(B, x[6:])
            uv, _ = lens.project(Bx.apply(obj))
            L = moved(E, x[:6]) @ Bx  # board_to_laser
            normal = L.rotation[:, 2]
            ranges = (normal @ L.translation) / (beams @ normal)
            return np.r_[uv.ravel() / pixel_noise, ranges / range_noise]

        h = 1e-6
        J = np.column_stack([(measure(h * e) - measure(-h * e)) / (2 * h) for e in np.eye(12)])
        idx = np.r_[0:6, 6 + 6 * i : 12 + 6 * i]
        info[np.ix_(idx, idx)] += J.T @ J
    return np.asarray(np.linalg.inv(info)[:6, :6])


def _bound_stats(covs: Sequence[np.ndarray], samples: int, seed: int = 0) -> dict[str, float]:
    """Median and p95 errors of draws from N(0, cov) pooled over ``covs``."""
    rng = np.random.default_rng(seed)
    draws = [rng.multivariate_normal(np.zeros(6), c, samples) for c in covs]
    return _stats(list(np.concatenate(draws)))


def _error_vector(estimate: Rigid, truth: Rigid) -> np.ndarray:
    """Left rotation vector (rad) and translation error (m), as ExtrinsicResult.std."""
    dR = estimate.rotation @ truth.rotation.T
    return np.r_[rotvec_from_matrix(dR), estimate.translation - truth.translation]


def _stats(errors: Sequence[np.ndarray]) -> dict[str, float]:
    e = np.array(errors)
    rot = np.degrees(np.linalg.norm(e[:, :3], axis=1))
    tr = np.linalg.norm(e[:, 3:], axis=1) * 1e3
    return {
        "rot_deg_median": round(float(np.median(rot)), 4),
        "rot_deg_p95": round(float(np.percentile(rot, 95)), 4),
        "t_mm_median": round(float(np.median(tr)), 3),
        "t_mm_p95": round(float(np.percentile(tr, 95)), 3),
    }


def _line(bench: str, **fields: object) -> None:
    print(json.dumps({"bench": bench, **fields}), flush=True)


def _run(
    datasets: Sequence[BoardData],
    n: int | None,
    method: Callable[[list[BoardPose]], Rigid | ex.ExtrinsicResult],
) -> tuple[list[np.ndarray], list[np.ndarray], int, int]:
    """(errors, stds, failures, warnings) of ``method`` on the first n poses of each set."""
    errors, stds, failures, warned = [], [], 0, 0
    for data in datasets:
        poses = data.poses[:n] if n else data.poses
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                out = method(poses)
            except ValueError:
                failures += 1
                continue
        warned += len(caught)
        rigid = out.camera_to_laser if isinstance(out, ex.ExtrinsicResult) else out
        errors.append(_error_vector(rigid, data.truth))
        if isinstance(out, ex.ExtrinsicResult):
            stds.append(out.std)
    return errors, stds, failures, warned


def _std_ratio(errors: list[np.ndarray], stds: list[np.ndarray]) -> list[float]:
    rms = np.sqrt(np.mean(np.square(errors), axis=0))
    return [round(float(x), 2) for x in np.mean(stds, axis=0) / rms]


def rig_two_cameras(poses: int, seed: int = 0) -> None:
    """The ``rig_two_cameras`` line (module docstring)."""
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        log = write_board_log(work, n_poses=poses, seed=seed, hold_s=1.5,
                              rig=default_rig(cameras=2))  # fmt: skip
        intr, out = work / "intrinsics.yaml", work / "calib.yaml"
        calibfile.save(log.calibration, intr)
        report = io.StringIO()
        t = time.perf_counter()
        with contextlib.redirect_stdout(report):
            argv = ["calibrate", "extrinsic", *map(str, log.files), "--intrinsics", str(intr),
                    "--board", log.spec, "-o", str(out), "--json"]  # fmt: skip
            assert acq_main(argv) == 0
        wall = time.perf_counter() - t
        cal = calibfile.load(out)
    fields: dict[str, object] = {"poses_per_camera": poses, "hold_s": 1.5, "seed": seed}
    for name, truth in log.truths.items():
        rot, trans = relative_pose.difference(cal.camera(name).camera_to_laser, truth)
        fields[name] = {"rot_deg": round(rot, 4), "t_mm": round(trans * 1e3, 2)}
    [rel] = json.loads(report.getvalue())["relative"]
    got = cal.camera("right").camera_to_laser.inverse() @ cal.camera("left").camera_to_laser
    truth = log.truths["right"].inverse() @ log.truths["left"]
    rot, trans = relative_pose.difference(got, truth)
    fields["left_to_right"] = {
        "rot_deg": round(rot, 4), "t_mm": round(trans * 1e3, 2),
        "std_rot_deg": rel["std_deg"], "std_t_mm": round(rel["std_m"] * 1e3, 2),
    }  # fmt: skip
    _line("rig_two_cameras", **fields, wall_s=round(wall, 1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--rig", action="store_true", help="only the two-camera rig's line")
    ap.add_argument("--rig-poses", type=int, default=15, help="board poses a camera")
    ap.add_argument("--rig-seed", type=int, default=0, help="the board poses' seed")
    args = ap.parse_args()
    if args.rig:
        rig_two_cameras(args.rig_poses, args.rig_seed)
        return
    seeds = range(args.seeds)

    t0 = time.perf_counter()
    data30 = [simulate(30, seed=s) for s in seeds]
    sim_s = (time.perf_counter() - t0) / (30 * args.seeds)

    methods: dict[str, Callable[[list[BoardPose]], Rigid | ex.ExtrinsicResult]] = {
        "linear": linear_solution,
        "exact_planes": lambda p: ex.calibrate(p, plane_errors=False),
        "default": ex.calibrate,
    }
    summary: dict[str, dict[str, float]] = {}
    for name, method in methods.items():
        t0 = time.perf_counter()
        errors, stds, failures, warned = _run(data30, 20, method)
        ms = (time.perf_counter() - t0) / args.seeds * 1e3
        extra: dict[str, object] = {}
        if stds:
            extra["std_ratio"] = _std_ratio(errors, stds)
        summary[name] = _stats(errors)
        _line(
            "poses20",
            method=name,
            seeds=args.seeds,
            **summary[name],
            **extra,
            failures=failures,
            warnings=warned,
            ms_per_calibration=round(ms, 1),
        )
    _line("simulation", ms_per_pose=round(sim_s * 1e3, 2))

    first20 = [dataclasses.replace(d, poses=d.poses[:20], boards=d.boards[:20]) for d in data30]
    bound = _bound_stats([cramer_rao(d) for d in first20], samples=2000)
    d = summary["default"]
    _line(
        "cramer_rao",
        poses=20,
        seeds=args.seeds,
        **bound,
        efficiency_rot=round(d["rot_deg_median"] / bound["rot_deg_median"], 3),
        efficiency_t=round(d["t_mm_median"] / bound["t_mm_median"], 3),
    )

    still: dict[tuple[int, int], dict[str, float]] = {}
    for frames, scans in STILL:
        held = [simulate(20, seed=4000 + s, frames=frames, scans=scans) for s in seeds]
        errors, stds, failures, _ = _run(held, None, ex.calibrate)
        still[frames, scans] = _stats(errors)
        _line(
            "still_pose",
            poses=20,
            frames=frames,
            scans=scans,
            **_stats(errors),
            std_ratio=_std_ratio(errors, stds),
            failures=failures,
        )

    for n in POSE_COUNTS:
        for name in ("exact_planes", "default"):
            errors, stds, failures, warned = _run(data30, n, methods[name])
            extra = {"std_ratio": _std_ratio(errors, stds)} if stds else {}
            _line(
                "vs_poses",
                poses=n,
                method=name,
                **_stats(errors),
                **extra,
                failures=failures,
                warnings=warned,
            )

    detected = missed = false_drops = 0
    errors = []
    for s in seeds:
        data = simulate(20, seed=1000 + s, n_outliers=2)
        result = ex.calibrate(data.poses)
        truth_out, found = set(data.outliers), set(result.outliers)
        detected += len(truth_out & found)
        missed += len(truth_out - found)
        false_drops += len(found - truth_out)
        errors.append(_error_vector(result.camera_to_laser, data.truth))
    _line(
        "outliers",
        poses=20,
        outlier_poses=2 * args.seeds,
        detected=detected,
        missed=missed,
        good_poses_dropped=false_drops,
        **_stats(errors),
    )

    near = [simulate(20, seed=2000 + s, distance=(1.0, 2.0)) for s in seeds]
    errors, stds, _, _ = _run(near, None, ex.calibrate)
    _line(
        "near",
        poses=20,
        distance_m=[1.0, 2.0],
        **_stats(errors),
        std_ratio=_std_ratio(errors, stds),
    )

    # the paper's way (§3.2): a regular lens on the camera for the extrinsic calibration
    rig = default_rig()
    pinhole = Pinhole(width=780, height=582, fx=600.0, fy=600.0, cx=390.0, cy=291.0)
    regular = rig.with_camera(lens=pinhole)
    datasets = [
        simulate(20, seed=3000 + s, rig=regular, distance=(1.5, 4.0), bearing_spread_deg=20.0)
        for s in seeds
    ]
    errors, stds, _, _ = _run(datasets, None, ex.calibrate)
    _line(
        "regular_lens",
        poses=20,
        lens="pinhole f=600 px (66 x 52 deg)",
        distance_m=[1.5, 4.0],
        bearing_spread_deg=20.0,
        **_stats(errors),
        std_ratio=_std_ratio(errors, stds),
    )

    d = summary["default"]
    h = still[STILL[1]]
    _line(
        "targets",
        poses=20,
        rot_target_deg=0.1,
        t_target_mm=5.0,
        one_frame_rot_deg_median=d["rot_deg_median"],
        one_frame_rot_ok=d["rot_deg_median"] <= 0.1,
        one_frame_bound_rot_deg_median=bound["rot_deg_median"],
        one_frame_t_mm_median=d["t_mm_median"],
        one_frame_t_ok=d["t_mm_median"] <= 5.0,
        still_frames_scans=list(STILL[1]),
        still_rot_deg_median=h["rot_deg_median"],
        still_rot_ok=h["rot_deg_median"] <= 0.1,
        still_t_mm_median=h["t_mm_median"],
        still_t_ok=h["t_mm_median"] <= 5.0,
    )
    assert math.isfinite(d["rot_deg_median"])


if __name__ == "__main__":
    main()
