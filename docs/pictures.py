"""The documentation's pictures, drawn from the simulated rig by acq's own commands
(`make docs-pictures`; committed, so `make docs` needs no rig):

- ``demo_preview.png``: the preview of a 3 s `acq demo` (both sides of the street, a top
  view, which camera coloured what);
- ``fisheye_circle.png``: `acq calibrate fisheye`'s overlay of the image circle on one
  simulated frame;
- ``extrinsic_residuals.png``: `acq calibrate extrinsic`'s residual plot on the simulated
  board recording;
- ``status.txt``: what `acq status` shows of the demo's log (a pipe gets one plain
  snapshot), for the page to show as a terminal.

Usage: ``python docs/pictures.py OUT_DIR``.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path


def acq(*argv: str, cwd: Path) -> str:
    """``acq ARGV`` in ``cwd`` as a user runs it; what it printed. A failure stops the
    script, its output shown."""
    done = subprocess.run(
        [sys.executable, "-m", "acq.cli", *argv], cwd=cwd, capture_output=True, text=True
    )
    if done.returncode != 0:
        raise SystemExit(
            f"acq {' '.join(argv)}: exit {done.returncode}\n{done.stdout}{done.stderr}"
        )
    return done.stdout


def draw(out: Path) -> list[Path]:
    """Every picture into ``out``; their paths."""
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="acq-pictures-") as tmp:
        work = Path(tmp)
        acq("demo", "--out", "demo", "--seconds", "3", cwd=work)
        shutil.copyfile(work / "demo" / "preview.png", out / "demo_preview.png")
        status = acq("status", "demo/demo.mcap", cwd=work)
        (out / "status.txt").write_text(status.replace(str(work) + "/", ""))

        acq("sim", "render", "--out", "street", "--equidistant", cwd=work)
        acq("calibrate", "fisheye", "street/frame.png", "--fov", "185", "-o", "fisheye.yaml",
            cwd=work)  # fmt: skip
        shutil.copyfile(work / "fisheye_circle.png", out / "fisheye_circle.png")

        acq("sim", "log", "board", "--out", "board", cwd=work)
        acq("calibrate", "extrinsic", "board", "--intrinsics", "board/intrinsics.yaml",
            "--board", "9x7x0.1", "-o", "board/calib.yaml", cwd=work)  # fmt: skip
        shutil.copyfile(work / "board" / "calib_extrinsic.png", out / "extrinsic_residuals.png")
    return sorted(out.iterdir())


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    for path in draw(Path(sys.argv[1])):
        print(path)
