"""acq colorize on a drive whose camera sent frames that do not decode as JPEG: the
others colour the cloud, and the report counts and names the broken ones (a real MCAP
log, sim/drive_log.py, its frames replaced by acq.log.writer)."""

from __future__ import annotations

from pathlib import Path

import pytest

from acq.cli import main as acq_main
from acq.log.locate import first_log_time
from acq.sim.drive_log import DriveTruth
from tests.log_rewrite import rewrite
from tests.strict_json import strict_json

# a JPEG's start-of-image marker, then bytes no decoder accepts
BROKEN = b"\xff\xd8\xff\xe0" + bytes(range(256)) * 4


def test_frames_that_do_not_decode_are_counted_and_the_first_named(
    short_drive: tuple[DriveTruth, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    truth, calib = short_drive
    files, times = rewrite(truth.files, tmp_path, frames={10: BROKEN, 31: BROKEN})
    out = tmp_path / "c.ply"
    argv = ["colorize", *map(str, files), "--calib", str(calib), "-o", str(out), "--no-preview"]
    assert acq_main(argv) == 0
    text = capsys.readouterr().out
    into = (times[10] - (first_log_time(files[0]) or 0)) * 1e-9
    assert (
        "note: 2 frames that do not decode as JPEG skipped; the first at "
        f"log time {times[10] * 1e-9:.3f} s, {into:.2f} s into {files[0]}"
    ) in text.splitlines(), text
    assert "(2 do not decode: see the note)" in text, text


def test_a_camera_whose_frames_all_fail_says_why_and_its_json_is_json(
    short_drive: tuple[DriveTruth, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Every frame broken: no point coloured, and the JSON report (strict RFC 8259, no
    NaN) counts them."""
    truth, calib = short_drive
    files, _ = rewrite(truth.files, tmp_path, frames=dict.fromkeys(range(100), BROKEN))
    out = tmp_path / "c.ply"
    argv = ["colorize", *map(str, files), "--calib", str(calib), "-o", str(out), "--no-preview"]
    assert acq_main([*argv, "--json"]) == 0
    report = strict_json(capsys.readouterr().out)
    assert isinstance(report, dict)
    assert report["coloured"] == 0
    n = report["frames"]
    assert n > 40 and report["frames_failed"] == n
    (camera,) = report["cameras"].values()
    assert camera["frames_undecodable"] == n
    assert any(f"{n} frames that do not decode as JPEG skipped" in s for s in report["notes"])
