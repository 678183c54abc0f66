"""`acq calibrate time-offset` on `acq demo`'s recordings against the demo's own truth,
one JSON line per run and camera, then one summary line.

Per run: `acq demo --out DIR` (the simulated rig recorded live by the real recorder),
the true ``time_offset_s`` of each camera from its summary (camera minus laser time:
re-timed frames minus re-timed scans, :mod:`acq.sim.demo_truth`), then `acq calibrate
time-offset DIR/demo.mcap --calib DIR/calib.yaml --json`: the estimate, its standard
error, the error (ms) and the error over the standard error. The summary, per camera:
the mean error and its standard error (a bias would show), the errors' RMS (ms), and
the RMS and largest |error| / standard error (about 1 and 2 when the standard error
is right). Each run records in real time: run it on a quiet machine.

Run as a script: ``python bench/time_offset_demo.py [--runs N] [--seconds S]``.
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3, help="demo recordings (default 3)")
    parser.add_argument("--seconds", type=float, default=10.0, help="each (default 10)")
    args = parser.parse_args()
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for run in range(args.runs):
            out = Path(tmp) / f"demo{run}"
            truth = _truth(demo.run(out, args.seconds).lines)
            for name, est in _estimates(out).items():
                value, se = 1e3 * est["offset_s"], 1e3 * est["std_s"]
                row = {
                    "run": run, "camera": name, "truth_ms": truth[name],
                    "estimate_ms": round(value, 3), "se_ms": round(se, 3),
                    "error_ms": round(value - truth[name], 3),
                    "error_over_se": round((value - truth[name]) / se, 2),
                }  # fmt: skip
                rows.append(row)
                print(json.dumps(row), flush=True)
    summary: dict[str, Any] = {"runs": args.runs, "seconds": args.seconds}
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
    print(json.dumps({"summary": summary}))


if __name__ == "__main__":
    main()
