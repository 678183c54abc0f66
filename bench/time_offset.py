"""`acq calibrate time-offset`'s estimate against the truth, one JSON line per recording
and camera, then one summary line per kind of recording.

- ``demo``: `acq demo --out DIR` (the simulated rig recorded live by the real recorder;
  the same street every run), the true ``time_offset_s`` of each camera from its summary
  (camera minus laser time: re-timed frames minus re-timed scans,
  :mod:`acq.sim.demo_truth`), then `acq calibrate time-offset DIR/demo.mcap --calib
  DIR/calib.yaml --json`. Each run records in real time: a quiet machine.
- ``drive``: :func:`acq.sim.drive_log.write_drive_log` (a left and a right camera, 4 s,
  another street per seed), the truth from its :class:`DriveTruth` (the same
  difference), the estimate as `acq calibrate time-offset` makes it.

Per recording and camera: the estimate, its standard error, the error (ms) and the error
over the standard error. The summary, per camera: the mean error and its standard error
(a bias would show), the errors' RMS (ms); and the RMS and largest |error| / standard
error (about 1 and 2 when the standard error is right).

Run as a script: ``python bench/time_offset.py [--demo-runs N] [--drives N]``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import re
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from acq.cli import main as acq_main
from acq.sim import demo
from acq.sim.demo_rig import CAMERAS


def _truth(lines: list[str]) -> dict[str, float]:
    """Each camera's true time_offset_s (ms) from the demo's summary."""
    text = "\n".join(lines)
    out = {}
    for name in CAMERAS:
        m = re.search(rf"{name} frame stamps .*\n +time_offset_s ([-+][\d.]+) ms", text)
        if m is None:
            raise SystemExit(f"the demo's summary has no true time_offset_s for {name}")
        out[name] = float(m.group(1))
    return out


def _estimates(out: Path) -> dict[str, dict[str, Any]]:
    """`acq calibrate time-offset --json` on the demo's log, by camera."""
    argv = ["calibrate", "time-offset", str(out / "demo.mcap"), "--calib",
            str(out / "calib.yaml"), "-o", str(out / "estimated.yaml"), "--json"]  # fmt: skip
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = acq_main(argv)
    if code != 0:
        raise SystemExit(f"acq calibrate time-offset exited {code}")
    report = json.loads(printed.getvalue())
    return {c["camera"]: c for c in report["cameras"]}


def _drive_truth(seed: int, directory: Path) -> tuple[dict[str, float], dict[str, Any]]:
    """A simulated drive's true time_offset_s per camera (ms) and the estimates."""
    from acq.cloud.colorize import Report, estimate_offset, prepare
    from acq.cloud.job import remap
    from acq.sim.drive_log import write_drive_log
    from acq.sim.world import default_rig

    truth = write_drive_log(directory, 4.0, pattern_at=None, seed=seed, rig=default_rig(cameras=2))
    job, whole = prepare(truth.files, truth.calibration, Report(output="x"), jpegs=True)
    scans = remap(job.scan_old, job.scan_new, truth.scan_stamp_ns)
    scan_err = np.mean(scans - (truth.start_ns + truth.scan_t0_s * 1e9))
    true_ms, found = {}, {}
    for cj in job.cameras:
        c = truth.cameras[cj.name]
        frames = remap(cj.frame_old, cj.frame_new, c.frame_stamp_ns)
        frame_err = np.mean(frames - (truth.start_ns + c.frame_t_s * 1e9))
        true_ms[cj.name] = float(frame_err - scan_err) * 1e-6
        est = estimate_offset(job, camera=cj, whole=whole, threads=2)
        found[cj.name] = {"offset_s": est.offset_s, "std_s": est.std_s}
    return true_ms, found


def _row(kind: str, run: int, name: str, truth_ms: float, est: dict[str, Any]) -> dict[str, Any]:
    value, se = 1e3 * est["offset_s"], 1e3 * est["std_s"]
    return {
        "kind": kind, "run": run, "camera": name, "truth_ms": round(truth_ms, 3),
        "estimate_ms": round(value, 3), "se_ms": round(se, 3),
        "error_ms": round(value - truth_ms, 3),
        "error_over_se": round((value - truth_ms) / se, 2),
    }  # fmt: skip


def _summary(kind: str, rows: list[dict[str, Any]]) -> dict[str, Any]:
    summary: dict[str, Any] = {"kind": kind, "recordings": len({r["run"] for r in rows})}
    for name in CAMERAS:
        e = np.array([r["error_ms"] for r in rows if r["camera"] == name])
        se_mean = float(e.std(ddof=1) / np.sqrt(e.size)) if e.size > 1 else float("nan")
        summary[name] = {
            "mean_error_ms": round(float(e.mean()), 3),
            "se_of_mean_ms": round(se_mean, 3),
            "rms_error_ms": round(float(np.sqrt(np.mean(e**2))), 3),
        }
    z = np.array([r["error_over_se"] for r in rows])
    summary["error_over_se"] = {
        "rms": round(float(np.sqrt(np.mean(z**2))), 2),
        "max_abs": round(float(np.abs(z).max()), 2),
    }
    return summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--demo-runs", type=int, default=2, help="demo recordings (default 2)")
    parser.add_argument("--drives", type=int, default=10, help="simulated drives (default 10)")
    args = parser.parse_args()
    kinds: dict[str, list[dict[str, Any]]] = {"demo": [], "drive": []}
    with tempfile.TemporaryDirectory() as tmp:
        for run in range(args.demo_runs):
            out = Path(tmp) / f"demo{run}"
            truth = _truth(demo.run(out, 10.0).lines)
            for name, est in _estimates(out).items():
                kinds["demo"].append(_row("demo", run, name, truth[name], est))
                print(json.dumps(kinds["demo"][-1]), flush=True)
        for seed in range(args.drives):
            true_ms, found = _drive_truth(seed, Path(tmp) / f"drive{seed}")
            for name, est in found.items():
                kinds["drive"].append(_row("drive", seed, name, true_ms[name], est))
                print(json.dumps(kinds["drive"][-1]), flush=True)
    for kind, rows in kinds.items():
        if rows:
            print(json.dumps({"summary": _summary(kind, rows)}), flush=True)


if __name__ == "__main__":
    main()
