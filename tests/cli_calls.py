"""The `acq` commands the tests run in-process, with the arguments as Python values: each
builds the command line and returns `acq.cli.main`'s exit status."""

from __future__ import annotations

import contextlib
import functools
import io
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from unittest import mock

from acq.cli import main


def printed(command: Callable[..., int], *args: object, **kwargs: object) -> tuple[int, str, str]:
    """``command(*args, **kwargs)`` (``main`` or one of the calls below) run in this
    process: its exit status and what it wrote on stdout and stderr. For fixtures wider
    than one test, where capsys cannot be had."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = command(*args, **kwargs)
    return code, out.getvalue(), err.getvalue()


def _opt(flag: str, value: object) -> list[str]:
    return [] if value is None else [flag, str(value)]


def calibrate_fisheye(
    images: Sequence[Path],
    fov_deg: float,
    output: Path,
    camera: str | None = None,
    ellipse: bool = False,
    json_out: bool = False,
    overlay: Path | None = None,
    board: str | None = None,
) -> int:
    return main([
        "calibrate", "fisheye", *map(str, images), "--fov", str(fov_deg), "-o", str(output),
        *_opt("--camera", camera), *_opt("--overlay", overlay), *_opt("--board", board),
        *(["--ellipse"] if ellipse else []), *(["--json"] if json_out else []),
    ])  # fmt: skip


def calibrate_extrinsic(
    logs: Sequence[Path],
    camera: str | None,
    intrinsics: Path,
    board: str,
    output: Path,
    poses: str | None = None,
    json_out: bool = False,
    plot: Path | None = None,
    lens_swap: Path | None = None,
    pupil_shift_m: float = 0.0,
) -> int:
    return main([
        "calibrate", "extrinsic", *map(str, logs), "--intrinsics", str(intrinsics),
        "--board", board, "-o", str(output), *_opt("--camera", camera),
        *_opt("--poses", poses), *_opt("--plot", plot), *_opt("--lens-swap", lens_swap),
        "--pupil-shift", repr(pupil_shift_m), *(["--json"] if json_out else []),
    ])  # fmt: skip


def calibrate_validate(
    logs: Sequence[Path],
    calib: Path,
    camera: str | None = None,
    json_out: bool = False,
    out: Path | None = None,
) -> int:
    return main([
        "calibrate", "validate", *map(str, logs), "--calib", str(calib),
        *_opt("--camera", camera), *_opt("-o", out), *(["--json"] if json_out else []),
    ])  # fmt: skip


def analyze_sensitivity(
    calib: Path,
    logs: Sequence[Path],
    out: Path,
    camera_height_m: float = 2.0,
    building_distance_m: float = 10.0,
    json_out: bool = False,
    sigma: Mapping[str, float] | None = None,
) -> int:
    sigmas = [a for k, v in (sigma or {}).items() for a in ("--sigma", f"{k}={v!r}")]
    return main([
        "analyze", "sensitivity", *map(str, logs), "--calib", str(calib), "-o", str(out),
        "--camera-height", repr(camera_height_m), "--building-distance",
        repr(building_distance_m), *sigmas, *(["--json"] if json_out else []),
    ])  # fmt: skip


def devices(
    json_out: bool = False,
    reset: str | None = None,
    *,
    sysfs_root: str = "/sys",
    dev_root: str = "/dev",
) -> int:
    """`acq devices`, looking at ``sysfs_root`` and ``dev_root`` instead of the machine's."""
    from acq.record import devices as lib

    listing = functools.partial(lib.list_devices, sysfs_root, dev_root)
    resetting = functools.partial(lib.reset, dev_root=dev_root)
    with (
        mock.patch.object(lib, "list_devices", listing),
        mock.patch.object(lib, "reset", resetting),
    ):
        return main(["devices", *_opt("--reset", reset), *(["--json"] if json_out else [])])
