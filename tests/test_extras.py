"""The core install records, calibrates and colours; a command that needs an extra this
install lacks says so in one line naming the extra (exit status 2), before writing anything.

An extra's absence is made here at the lowest layer that can make it: ``sys.modules[name]
= None`` (with its loaded submodules) makes ``import name`` raise ImportError, as on an
install without that library; uninstalling packages mid-suite cannot be done. The wheel
smoke (tests/smoke/wheel.sh) checks a real core-only install.
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import pytest

from acq.cli import main as acq_main
from acq.extras import EXTRAS, MissingExtraError, needs
from acq.sim.drive_log import DriveTruth
from acq.sim.fisheye_images import fisheye_image

Drive = tuple[DriveTruth, Path]


def _block(monkeypatch: pytest.MonkeyPatch, *extras: str) -> None:
    """Make every library of ``extras`` unimportable for this test."""
    for extra in extras:
        for root in EXTRAS[extra]:
            for name in [n for n in sys.modules if n == root or n.startswith(root + ".")]:
                monkeypatch.setitem(sys.modules, name, None)
            monkeypatch.setitem(sys.modules, root, None)


def _one_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    return err.strip()


def _colorize(drive: Drive, out: Path, *more: str) -> list[str]:
    truth, calib = drive
    return ["colorize", *map(str, truth.files), "--calib", str(calib), "-o", str(out),
            "--no-preview", *more]  # fmt: skip


@pytest.mark.parametrize(
    ("extra", "output", "more", "what"),
    [
        ("cluster", "c.ply", ["--dask", "tcp://127.0.0.1:9"], "--dask"),
        ("e57", "c.e57", [], "-o {out}: E57 output"),
        ("copc", "c.copc.laz", [], "-o {out}: COPC output"),
    ],
)
def test_colorize_names_the_missing_extra(
    extra: str, output: str, more: list[str], what: str, short_drive: Drive, tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    _block(monkeypatch, extra)
    out = tmp_path / output
    assert acq_main(_colorize(short_drive, out, *more)) == 2
    assert _one_line(capsys) == (
        f"acq colorize: {what.format(out=out)} needs the {extra} extra: pip install 'acq[{extra}]'"
    )
    assert list(tmp_path.iterdir()) == []


def test_export_ros2_names_the_ros2_extra(
    short_drive: Drive, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    _block(monkeypatch, "ros2")
    truth, _ = short_drive
    assert acq_main(["export", "ros2", *map(str, truth.files), "-o", str(tmp_path / "bag")]) == 2
    assert _one_line(capsys) == (
        "acq export ros2: writing a rosbag2 bag needs the ros2 extra: pip install 'acq[ros2]'"
    )
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("output", "more", "what"),
    [("m.glb", [], "-o {out}: glTF output"), ("m.ply", ["--simplify", "0.01"], "--simplify")],
)
def test_mesh_names_the_mesh_extra(
    output: str, more: list[str], what: str, short_drive: Drive, tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    _block(monkeypatch, "mesh")
    truth, calib = short_drive
    out = tmp_path / output
    argv = ["mesh", *map(str, truth.files), "--calib", str(calib), "-o", str(out), *more]
    assert acq_main(argv) == 2
    assert _one_line(capsys) == (
        f"acq mesh: {what.format(out=out)} needs the mesh extra: pip install 'acq[mesh]'"
    )
    assert list(tmp_path.iterdir()) == []


def test_the_core_colours_calibrates_and_reads_without_any_extra(
    short_drive: Drive, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    _block(monkeypatch, *EXTRAS)
    truth, _ = short_drive
    for out in (tmp_path / "c.las", tmp_path / "c.ply", tmp_path / "c.laz"):
        assert acq_main(_colorize(short_drive, out)) == 0, capsys.readouterr().err
        assert out.stat().st_size > 0
    assert acq_main(["info", *map(str, truth.files)]) == 0
    assert "/laser/scan" in capsys.readouterr().out
    img, _ = fisheye_image(cx=386.6, cy=294.3, radius=274.2, rim=0.3, edge_width=2.0)
    cv2.imwrite(str(tmp_path / "frame.png"), img)
    lens = tmp_path / "lens.yaml"
    argv = ["calibrate", "fisheye", str(tmp_path / "frame.png"), "--fov", "185", "-o", str(lens)]
    assert acq_main(argv) == 0
    assert lens.stat().st_size > 0
    for extra in EXTRAS:  # none of them was imported on the way
        assert all(sys.modules[m] is None for m in EXTRAS[extra])


def test_needs_passes_another_import_error_through(monkeypatch: pytest.MonkeyPatch) -> None:
    _block(monkeypatch, "e57")
    with pytest.raises(MissingExtraError, match=r"E57 output needs the e57 extra"):
        with needs("e57", "E57 output"):
            import pye57  # noqa: F401
    monkeypatch.setitem(sys.modules, "no_such_acq_module", None)
    with pytest.raises(ImportError) as e, needs("e57", "E57 output"):
        import no_such_acq_module  # noqa: F401
    assert not isinstance(e.value, MissingExtraError)


def test_demo_names_the_mesh_extra_before_recording(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    _block(monkeypatch, "mesh")
    assert acq_main(["demo", "--seconds", "1", "--out", str(tmp_path / "demo")]) == 2
    assert _one_line(capsys) == (
        "acq demo: the demo's textured mesh needs the mesh extra: pip install 'acq[mesh]'"
    )
    assert list(tmp_path.iterdir()) == []


def test_reading_a_rosbag2_bag_names_the_ros2_extra(
    short_drive: Drive, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    truth, calib = short_drive
    bag = tmp_path / "bag"
    assert acq_main(["export", "ros2", *map(str, truth.files), "-o", str(bag)]) == 0
    capsys.readouterr()
    _block(monkeypatch, "ros2")
    out = tmp_path / "c.ply"
    assert acq_main(["colorize", str(bag), "--calib", str(calib), "-o", str(out)]) == 2
    assert _one_line(capsys) == (
        "acq colorize: reading a rosbag2 bag needs the ros2 extra: pip install 'acq[ros2]'"
    )
    assert not out.exists()
