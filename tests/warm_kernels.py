"""numba's cache of acq's kernels filled once, before the tests, as ``make compile`` fills
the bytecode: otherwise every test process that meets a kernel first compiles it, several
at once in a fresh checkout (about 50 s of CPU over the tests). The commands that compile
them, run on a 2 s simulated drive of the two-camera rig: ``python -m tests.warm_kernels``.
A command that fails here is said in one line and left to its tests."""

from __future__ import annotations

import contextlib
import io
import sys
import tempfile
import time
from pathlib import Path

from acq.camera import calibfile
from acq.cli import main as acq_main
from acq.sim.drive_log import write_drive_log
from acq.sim.world import default_rig


def main() -> int:
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="acq-warm-") as tmp:
        d = Path(tmp)
        truth = write_drive_log(d / "drive", 2.0, pattern_at=None, rig=default_rig(cameras=2))
        calib = str(d / "calib.yaml")
        calibfile.save(truth.calibration, Path(calib))
        logs = [str(f) for f in truth.files]
        for argv in (
            ["colorize", *logs, "--calib", calib, "-o", str(d / "c.ply")],
            ["colorize", *logs, "--calib", calib, "-o", str(d / "b.las"), "--view", "best"],
            ["mesh", *logs, "--calib", calib, "-o", str(d / "m.glb"), "--texture"],
            ["calibrate", "check", *logs, "--calib", calib, "--frames", "20"],
        ):
            out = io.StringIO()
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
                code = acq_main(argv)
            if code != 0:
                print(f"warm kernels: acq {' '.join(argv[:2])}: exit {code}: "
                      f"{out.getvalue().strip().splitlines()[-1:]}", file=sys.stderr)  # fmt: skip
    print(f"warm kernels: {time.monotonic() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
