"""The documentation's pictures, drawn from the simulated rig by acq's own commands
(`make docs-pictures`; committed, so `make docs` needs no rig):

- ``demo_preview.png``: the preview of a 3 s `acq demo` (both sides of the street, a top
  view, which camera coloured what);
- ``fisheye_circle.png``: `acq calibrate fisheye`'s overlay of the image circle on one
  simulated frame;
- ``extrinsic_residuals.png``: `acq calibrate extrinsic`'s residual plot on the simulated
  board recording;
- ``status.txt``: what `acq status` shows of the demo's log (a pipe gets one plain
  snapshot), for the page to show as text; ``status.svg`` the same full-screen view as a
  terminal shows it, drawn by rich (the library the view is made with);
- ``rig_frames.png``: the demo rig's frames (vehicle, laser, each camera) from its
  calib.yaml, seen from the side and from above;
- ``site_*.png``: three pages of this documentation site as built (`mkdocs build`), in
  headless Chromium: a how-to guide, the live one with `acq status`, the Python API;
- ``view_demo_drive.png``: `acq view` of the demo's log (its trajectory, a frustum per
  camera pose, its coloured cloud) in headless Chromium, WebGL in software (SwiftShader,
  as tests/browser.py drives it; `make chromium` installs it).

Usage: ``python docs/pictures.py OUT_DIR`` from the repository's root.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

from acq.camera import calibfile
from acq.geometry.transforms import Rigid
from acq.monitor.snapshot import STALE_S
from tests.browser import FLAGS

CHROMIUM = "/usr/bin/chromium"
PAGE_SIZE = (1280, 800)
# Chromium's flags for one screenshot: it exits once drawn (a debugging port keeps it on)
SHOT_FLAGS = [f for f in FLAGS if not f.startswith("--remote-debugging")]
PAGE_BUDGET_MS = 20000  # of the page's virtual time: the layers fetched, decoded, drawn


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


AXIS_M = 0.3  # drawn length of a frame's axes
VIEW_PX = (560, 420)  # each view's size
AXIS_BGR = ((60, 60, 230), (60, 170, 60), (230, 120, 40))  # x red, y green, z blue


def rig_frames(calib_path: Path, png: Path) -> None:
    """The vehicle's, the laser's and each camera's frame (x red, y green, z blue: a
    camera's z is its optical axis) in the vehicle frame (x ahead, y left, z up, metres),
    from the side (x, z) and from above (x, y)."""
    calib = calibfile.load(calib_path)
    laser = calib.laser_to_vehicle or Rigid.identity()
    frames = {"vehicle": Rigid.identity(), calib.laser: laser}
    for name, cam in calib.cameras.items():
        if cam.extrinsics is not None:
            frames[name] = laser @ cam.extrinsics
    tips = [f.translation + AXIS_M * f.rotation[:, k] for f in frames.values() for k in range(3)]
    ends = np.array(tips + [f.translation for f in frames.values()])
    views = []
    for title, (a, b), (name_a, name_b) in (
        ("from the side", (0, 2), ("x ahead", "z up")),
        ("from above", (0, 1), ("x ahead", "y left")),
    ):
        img = np.full((VIEW_PX[1], VIEW_PX[0], 3), 255, np.uint8)
        lo, hi = ends[:, [a, b]].min(axis=0) - 0.3, ends[:, [a, b]].max(axis=0) + 0.3
        scale = min((VIEW_PX[0] - 40) / (hi[0] - lo[0]), (VIEW_PX[1] - 80) / (hi[1] - lo[1]))

        def px(
            p: np.ndarray, a: int = a, b: int = b, lo: np.ndarray = lo, s: float = scale
        ) -> tuple[int, int]:
            return int(20 + (p[a] - lo[0]) * s), int(VIEW_PX[1] - 20 - (p[b] - lo[1]) * s)

        labels: list[tuple[int, int]] = []
        for name, f in frames.items():
            o = px(f.translation)
            for k in range(3):
                cv2.arrowedLine(img, o, px(f.translation + AXIS_M * f.rotation[:, k]),
                                AXIS_BGR[k], 2, cv2.LINE_AA, tipLength=0.15)  # fmt: skip
            at = (o[0] + 6, o[1] + 18)
            while any(abs(at[0] - u) < 60 and abs(at[1] - v) < 16 for u, v in labels):
                at = (at[0], at[1] + 16)  # frames at one place: their names one under another
            labels.append(at)
            cv2.putText(img, name, at, cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
        label = f"{title}: {name_a}, {name_b} (m; axes x red, y green, z blue)"
        cv2.putText(img, label, (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
        views.append(img)
    cv2.imwrite(
        str(png), np.hstack([views[0], np.full((VIEW_PX[1], 8, 3), 200, np.uint8), views[1]])
    )


def status_shot(log: str, svg: Path, cwd: Path) -> None:
    """`acq status LOG`'s full-screen view (its first frame), as a terminal shows it, to
    ``svg``: rich's recording console renders the view `acq status` renders."""
    from rich.console import Console

    from acq.monitor.log_source import LogSource
    from acq.monitor.view import render

    with contextlib.chdir(cwd):
        source = LogSource(Path(log))
        try:
            snap = source.snapshot()
        finally:
            source.close()
    with open(os.devnull, "w") as sink:
        console = Console(record=True, width=128, force_terminal=True, file=sink)
        console.print(render(snap, STALE_S))
    # rich's web fonts come from a CDN: the site is read offline, in a monospace font
    text = console.export_svg(title=f"acq status {log}")
    svg.write_text(re.sub(r"@font-face \{.*?\}\s*", "", text, flags=re.S))


SITE_PAGES = ("how-to/record", "how-to/watch-live", "reference/api")


def site_shots(out: Path) -> None:
    """The site built (strict) and :data:`SITE_PAGES` drawn by headless Chromium into
    ``out/site_<name>.png``."""
    with tempfile.TemporaryDirectory(prefix="acq-site-") as tmp:
        subprocess.run(
            [sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet", "-d", tmp],
            check=True, env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
        )  # fmt: skip
        for page in SITE_PAGES:
            png = out / f"site_{page.rsplit('/', 1)[-1]}.png"
            subprocess.run(
                [CHROMIUM, *SHOT_FLAGS, "--window-size=1280,1400", f"--screenshot={png}",
                 f"file://{tmp}/{page}.html"],
                check=True, capture_output=True, timeout=120,
            )  # fmt: skip


def page_shot(paths: list[str], png: Path, cwd: Path) -> None:
    """`acq view PATHS` served, its page drawn by headless Chromium into ``png``."""
    view = subprocess.Popen(
        [sys.executable, "-m", "acq.cli", "view", *paths], cwd=cwd, text=True,
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
    )  # fmt: skip
    try:
        assert view.stdout is not None
        line = view.stdout.readline()  # "serving N layers at URL (Ctrl-C to stop)"
        if " at http://" not in line:
            raise SystemExit(f"acq view {' '.join(paths)}: {line}{view.stdout.read()}")
        url = line.split(" at ", 1)[1].split()[0]
        subprocess.run(
            [CHROMIUM, *SHOT_FLAGS, f"--window-size={PAGE_SIZE[0]},{PAGE_SIZE[1]}",
             f"--virtual-time-budget={PAGE_BUDGET_MS}", f"--screenshot={png}", url],
            check=True, capture_output=True, timeout=120,
        )  # fmt: skip
    finally:
        view.send_signal(signal.SIGINT)  # how a user stops it
        view.wait(timeout=30)


def draw(out: Path) -> list[Path]:
    """Every picture into ``out``; their paths."""
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="acq-pictures-") as tmp:
        work = Path(tmp)
        acq("demo", "--out", "demo", "--seconds", "3", cwd=work)
        shutil.copyfile(work / "demo" / "preview.png", out / "demo_preview.png")
        status = acq("status", "demo/demo.mcap", cwd=work)
        (out / "status.txt").write_text(status.replace(str(work) + "/", ""))
        status_shot("demo/demo.mcap", out / "status.svg", cwd=work)
        page_shot(["demo/demo.mcap"], out / "view_demo_drive.png", cwd=work)
        rig_frames(work / "demo" / "calib.yaml", out / "rig_frames.png")

        acq("sim", "render", "--out", "street", "--equidistant", cwd=work)
        acq("calibrate", "fisheye", "street/frame.png", "--fov", "185", "-o", "fisheye.yaml",
            cwd=work)  # fmt: skip
        shutil.copyfile(work / "fisheye_circle.png", out / "fisheye_circle.png")

        acq("sim", "log", "board", "--out", "board", cwd=work)
        acq("calibrate", "extrinsic", "board", "--intrinsics", "board/intrinsics.yaml",
            "--board", "9x7x0.1", "-o", "board/calib.yaml", cwd=work)  # fmt: skip
        shutil.copyfile(work / "board" / "calib_extrinsic.png", out / "extrinsic_residuals.png")
    site_shots(out)
    return sorted(out.iterdir())


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    for path in draw(Path(sys.argv[1])):
        print(path)
