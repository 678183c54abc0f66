"""The logs a command reads (acq.log.inputs): files or folders alike for every command,
sessions never merged, a repaired copy or a copy read once, a calibration of another
image size refused, `acq info` on a file being written, outputs into missing folders."""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.writer import Writer
from plyfile import PlyData

from acq.camera import calibfile
from acq.cli import main as acq_main
from acq.log import schemas
from acq.log.reader import LogError, LogReader
from acq.log.repair import repair
from acq.log.writer import LogWriter
from acq.sim.drive_log import DriveTruth, write_drive_log


@pytest.fixture(scope="module")
def drives(tmp_path_factory: pytest.TempPathFactory) -> tuple[DriveTruth, DriveTruth, Path]:
    """Two short drives, each its own session (same simulated clock, same street), and
    their calibration."""
    root = tmp_path_factory.mktemp("drives")
    a = write_drive_log(root / "a", 0.6, pattern_at=None)
    b = write_drive_log(root / "b", 0.6, seed=1, pattern_at=None)
    calib = root / "calib.yaml"
    calibfile.save(a.calibration, calib)
    return a, b, calib


def _session_files(paths: list[Path]) -> list[Path]:
    from acq.log import inputs

    return inputs.session_files(paths)


def _being_written(path: Path) -> bool:
    from acq.log.writer_lock import being_written

    return being_written(path)


def _scans(path: Path) -> int:
    return sum(1 for _, c, _ in LogReader(path).messages() if c.topic.endswith("/scan"))


def _points(ply: Path) -> int:
    return len(PlyData.read(str(ply))["vertex"].data)


def _err(capsys: pytest.CaptureFixture[str]) -> str:
    return capsys.readouterr().err


# --- sessions ---------------------------------------------------------------------------


def test_two_sessions_are_refused_naming_both_and_info_shows_each(
    drives: tuple[DriveTruth, DriveTruth, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a, b, calib = drives
    (fa,), (fb,) = a.files, b.files
    for argv in (
        ["colorize", str(fa), str(fb), "--calib", str(calib), "-o", str(tmp_path / "c.ply")],
        ["export", "ros2", str(fa.parent), str(fb.parent), "-o", str(tmp_path / "bag")],
    ):
        assert acq_main(argv) == 2
        err = _err(capsys)
        assert err.count("\n") == 1 and "2 recording sessions given" in err
        assert str(fa) in err and str(fb) in err
    assert not (tmp_path / "c.ply").exists() and not (tmp_path / "bag").exists()

    assert acq_main(["info", "--json", str(fa), str(fb)]) == 0
    data = json.loads(capsys.readouterr().out)
    assert [len(d["files"]) for d in data] == [1, 1]  # no summary merging both
    assert acq_main(["info", str(fa), str(fb)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("2 recording sessions, each summarised on its own")
    assert "(2 files)" not in out


def test_the_parts_of_a_session_read_together_whatever_their_names(tmp_path: Path) -> None:
    w = LogWriter(tmp_path / "rec", prefix="p", split_s=0.1)
    w.add_channel("/acq/clock", schemas.SCHEMAS["acq.Clock"])
    for k in range(3):
        w.write(
            "/acq/clock", schemas.clock(realtime_ns=k, monotonic_ns=k), 10**9 + k * 2 * 10**8, 10**9
        )
    w.close()
    parts = [p.rename(tmp_path / f"renamed_{k}.mcap") for k, p in enumerate(w.files)]
    assert len(parts) == 3
    from acq.log import inputs

    found = inputs.sessions([parts[0], tmp_path])  # one given twice
    assert [s.files for s in found] == [parts]
    assert found[0].id == w.session


def _old_log(path: Path, acq: dict[str, str], first_ns: int) -> Path:
    """A log as acq wrote them before sessions had an id: its ``acq`` record, a message."""
    with path.open("wb") as f:
        w = Writer(f)
        w.start()
        w.add_metadata("acq", acq)
        channel = w.register_channel("/x", "", w.register_schema("raw", "", b""))
        w.add_message(channel, log_time=first_ns, data=b"x", publish_time=first_ns)
        w.finish()
    return path


def test_older_logs_are_grouped_by_the_recorders_start_or_their_names(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from acq.log import inputs

    one = {"host": "car", "started_utc": "2026-12-01T10:00:00Z"}
    other = {"host": "car", "started_utc": "2026-12-01T11:30:00Z"}
    a0 = _old_log(tmp_path / "a0.mcap", one, 10**9)
    a1 = _old_log(tmp_path / "a1.mcap", one, 2 * 10**9)
    b0 = _old_log(tmp_path / "b0.mcap", other, 10**9)
    assert [s.files for s in inputs.sessions([a0, a1, b0])] == [[a0, a1], [b0]]
    named = [_old_log(tmp_path / f"acq_20261201T100000Z_00{k}.mcap", {}, k * 10**9) for k in (0, 1)]
    assert inputs.session_files(named) == named
    assert acq_main(["info", str(a0), str(b0)]) == 0
    assert "2 recording sessions" in capsys.readouterr().out


# --- repaired copies and copies ---------------------------------------------------------


def test_a_repaired_copy_beside_its_log_is_read_once(
    drives: tuple[DriveTruth, DriveTruth, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    caplog: pytest.LogCaptureFixture,
) -> None:
    a, _, calib = drives
    folder = tmp_path / "logs"
    folder.mkdir()
    log = Path(shutil.copy(a.files[0], folder))
    assert acq_main(["info", "--repair", str(log)]) == 0
    assert (folder / (log.stem + ".repaired.mcap")).exists()
    capsys.readouterr()
    n = _scans(log)
    assert acq_main(["info", "--json", str(folder)]) == 0
    (summary,) = json.loads(capsys.readouterr().out)
    scans = next(c for c in summary["channels"] if c["topic"].endswith("/scan"))
    assert scans["count"] == n
    assert summary["files"] == [str(folder / (log.stem + ".repaired.mcap"))]

    one, both = tmp_path / "one.ply", tmp_path / "both.ply"
    base = ["--calib", str(calib), "--frame", "laser", "--no-preview"]
    assert acq_main(["colorize", str(log), *base, "-o", str(one)]) == 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no numpy warning either
        assert acq_main(["colorize", str(folder), *base, "-o", str(both)]) == 0
    copy = folder / (log.stem + ".repaired.mcap")
    assert f"{log} not read: the same recording as {copy} (its repaired copy" in caplog.text
    assert _points(both) == _points(one)


def test_a_plain_copy_of_a_log_is_read_once(
    drives: tuple[DriveTruth, DriveTruth, Path], tmp_path: Path
) -> None:
    a, _, _ = drives
    copy = Path(shutil.copy(a.files[0], tmp_path / "copy.mcap"))
    assert _session_files([a.files[0], copy]) == [a.files[0]]


def _clock_writer(directory: Path, prefix: str) -> LogWriter:
    w = LogWriter(directory, prefix=prefix)
    w.add_channel("/acq/clock", schemas.SCHEMAS["acq.Clock"])
    return w


def _write_clock(w: LogWriter, first: int, n: int) -> None:
    for k in range(first, first + n):
        w.write("/acq/clock", schemas.clock(realtime_ns=k, monotonic_ns=k), 10**9 + k * 10**8, 0)
    w.sync()


def test_a_log_that_grew_after_its_repair_is_read_whole(tmp_path: Path) -> None:
    """A copy repaired while the recorder still wrote: the log, grown since, is read."""
    w = _clock_writer(tmp_path, "live")
    _write_clock(w, 0, 5)
    log = w.path
    assert log is not None
    copy = tmp_path / "copy.mcap"
    assert repair(log, copy) == 5
    assert _session_files([tmp_path]) == [copy]  # the same messages, indexed
    _write_clock(w, 5, 5)  # the recorder went on
    w.close()
    assert _session_files([copy, log]) == [log]
    assert _scans_or_messages(log) == 10


def _scans_or_messages(path: Path) -> int:
    return sum(1 for _ in LogReader(path).messages())


# --- folders, outputs, messages ---------------------------------------------------------


def test_every_log_command_takes_a_folder(
    drives: tuple[DriveTruth, DriveTruth, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a, _, calib = drives
    folder = str(a.files[0].parent)
    assert acq_main(["info", folder]) == 0
    assert acq_main(["export", "ros2", folder, "-o", str(tmp_path / "bag")]) == 0
    sens = ["analyze", "sensitivity", folder, "--calib", str(calib), "-o", str(tmp_path / "s")]
    assert acq_main(sens) == 0
    capsys.readouterr()
    # these read the folder's log, and then find no board, pattern or device parameters
    # in this simulated drive: what they say is about those, not about a folder
    for argv in (
        ["replay", folder],
        ["calibrate", "extrinsic", folder, "--intrinsics", str(calib), "--board", "7x5x0.1",
         "-o", str(tmp_path / "e.yaml")],
        ["calibrate", "validate", folder, "--calib", str(calib)],
    ):  # fmt: skip
        acq_main(argv)
        err = _err(capsys)
        assert "folder" not in err and "directory" not in err, err


def test_a_folder_that_is_a_ros2_bag_or_holds_no_logs_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "bag").mkdir()
    (tmp_path / "bag" / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    (tmp_path / "bag" / "bag.mcap").write_bytes(b"\x89MCAP0\r\n")
    (tmp_path / "empty").mkdir()
    assert acq_main(["info", str(tmp_path / "bag")]) == 2
    assert "not a rosbag2 metadata file" in _err(capsys)
    assert acq_main(["replay", str(tmp_path / "empty")]) == 2
    assert _err(capsys) == f"acq replay: LOG {tmp_path / 'empty'}: no .mcap files in this folder\n"


@pytest.mark.parametrize(
    "argv",
    [
        ["colorize", "{log}", "--calib", "{calib}", "-o", "{missing}/cloud.ply"],
        ["info", "--repair", "{log}", "-o", "{missing}/copy.mcap"],
        ["export", "ros2", "{log}", "-o", "{missing}/bag"],
        ["calibrate", "time-offset", "{log}", "--calib", "{calib}", "-o", "{missing}/c.yaml"],
    ],
    ids=["colorize", "repair", "export", "time-offset"],
)
def test_an_output_into_a_missing_folder_names_it(
    argv: list[str],
    drives: tuple[DriveTruth, DriveTruth, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    a, _, calib = drives
    missing = tmp_path / "not" / "there"
    names = {"log": str(a.files[0]), "calib": str(calib), "missing": str(missing)}
    assert acq_main([arg.format(**names) for arg in argv]) == 2
    err = _err(capsys)
    assert f"the folder {tmp_path / 'not'} does not exist" in err and err.count("\n") == 1
    assert not (tmp_path / "not").exists()


def test_byte_offsets_only_where_they_mean_something(tmp_path: Path) -> None:
    empty, cut = tmp_path / "empty.mcap", tmp_path / "cut.mcap"
    empty.write_bytes(b"")
    cut.write_bytes(b"\x89MCA")
    for path, text in [
        (tmp_path, "is a folder, not an MCAP file"),
        (tmp_path / "missing.mcap", "no such file"),
        (empty, "empty file, not an MCAP file"),
    ]:
        with pytest.raises(LogError) as e:
            LogReader(path)
        assert str(e.value) == f"{path}: {text}"
    with pytest.raises(LogError, match=r"cut inside the MCAP magic, 4 bytes long \(byte 4\)$"):
        LogReader(cut)


# --- a calibration of another image size ------------------------------------------------


def test_a_calibration_of_another_image_size_is_refused_naming_both(
    drives: tuple[DriveTruth, DriveTruth, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a, _, calib = drives
    data = yaml.safe_load(calib.read_text())
    (name, cam), *_ = data["cameras"].items()
    w, h = cam["image_size"]
    cam["image_size"] = [w - 32, h - 102]
    cam["cx"], cam["cy"] = (w - 32) / 2, (h - 102) / 2
    wrong = tmp_path / "wrong.yaml"
    wrong.write_text(yaml.safe_dump(data))
    log = str(a.files[0])
    for argv in (
        ["colorize", log, "--calib", str(wrong), "-o", str(tmp_path / "c.ply")],
        ["calibrate", "validate", log, "--calib", str(wrong)],
    ):
        assert acq_main(argv) == 2
        err = _err(capsys)
        assert err.count("\n") == 1, err
        assert f"{wrong}: cameras.{name}.image_size is {w - 32}x{h - 102} px" in err
        assert f"the log's frames of camera {name} are {w}x{h} ({a.files[0].name})" in err


def test_one_camera_of_several_calibrated_at_another_size_is_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from acq.sim.world import default_rig

    two = write_drive_log(tmp_path, 0.3, rig=default_rig(cameras=2), pattern_at=None)
    right = tmp_path / "right.yaml"
    calibfile.save(two.calibration, right)
    data = yaml.safe_load(right.read_text())
    name = list(data["cameras"])[1]
    w, h = data["cameras"][name]["image_size"]
    data["cameras"][name].update(image_size=[640, 480], cx=320.0, cy=240.0)
    wrong = tmp_path / "wrong.yaml"
    wrong.write_text(yaml.safe_dump(data))
    argv = ["colorize", str(two.files[0]), "--calib", str(wrong), "-o", str(tmp_path / "c.ply")]
    assert acq_main(argv) == 2
    err = _err(capsys)
    assert f"cameras.{name}.image_size is 640x480 px" in err and f"are {w}x{h}" in err


# --- a file being written -----------------------------------------------------------------


def test_info_on_a_file_being_written_says_so_and_reads_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    w = _clock_writer(tmp_path, "live")
    _write_clock(w, 0, 5)
    path = w.path
    assert path is not None
    try:
        assert acq_main(["info", str(path)]) == 0
        out = capsys.readouterr().out
        assert f"{path}: BEING WRITTEN" in out and "NOT CLOSED" not in out
        assert "being written: its recorder is running" in out
        assert "the writer stopped" not in out
        assert "/acq/clock" in out and " 5 in 1 channels" in out
        assert _being_written(path)
    finally:
        w.close()
    assert not _being_written(path)
    assert acq_main(["info", str(path)]) == 0
    assert f"{path}: closed" in capsys.readouterr().out


def test_frame_retiming_of_stamps_read_twice_warns_nothing() -> None:
    from acq.time.retime import retime_frames

    stamps = np.arange(40, dtype=np.int64) * 40_000_000
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = retime_frames(np.repeat(stamps, 2))
    assert out.frame_ns.size == 80
