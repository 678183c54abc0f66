"""No command writes over one of its inputs, over a file of another kind, or over an
existing calibration without --force (and then keeps NAME.bak); `acq demo` refuses a
folder it did not write; a failed write names its file and leaves no half file."""

from __future__ import annotations

import hashlib
import random
import resource
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.writer import Writer

from acq.cli import main

MCAP_MAGIC = b"\x89MCAP0\r\n"


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _files(tmp_path: Path) -> dict[str, Path]:
    """A log, an image and a calibration as the commands' inputs (their content is never
    read: the outputs are refused first)."""
    log, img, cal = tmp_path / "drive.mcap", tmp_path / "frame.png", tmp_path / "calib.yaml"
    log.write_bytes(MCAP_MAGIC + bytes(range(256)) * 40)
    img.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(300))
    cal.write_text("version: 1\nlaser: laser\ncameras: {}\n")
    return {"log": log, "img": img, "cal": cal}


# (argv with {log}, {img}, {cal} for the files, the option that names the input)
SAME_AS_INPUT = [
    (["replay", "{log}", "--config-out", "{log}"], "--config-out"),
    (["replay", "{log}", "--config-out", "{log}", "--force"], "--config-out"),
    (["calibrate", "time-offset", "{log}", "--calib", "{cal}", "-o", "{log}"], "-o"),
    (["calibrate", "time-offset", "{log}", "--calib", "{cal}", "-o", "{log}", "--force"], "-o"),
    (
        [
            "calibrate",
            "extrinsic",
            "{log}",
            "--intrinsics",
            "{cal}",
            "--board",
            "9x7x0.1",
            "-o",
            "{log}",
        ],
        "-o",
    ),
    (
        [
            "calibrate",
            "extrinsic",
            "{log}",
            "--intrinsics",
            "{cal}",
            "--board",
            "9x7x0.1",
            "-o",
            "o.yaml",
            "--plot",
            "{log}",
        ],
        "--plot",
    ),
    (["calibrate", "fisheye", "{img}", "--fov", "185", "-o", "{img}"], "-o"),
    (
        ["calibrate", "fisheye", "{img}", "--fov", "185", "-o", "c.yaml", "--overlay", "{img}"],
        "--overlay",
    ),
    (["colorize", "{log}", "--calib", "{cal}", "-o", "c.ply", "--preview", "{log}"], "--preview"),
    (["colorize", "{log}", "--calib", "{cal}", "-o", "c.ply", "--preview", "{cal}"], "--preview"),
    (
        ["probe", "camera", "--driver", "opencv", "--source", "0", "--snapshot", "{log}"],
        "--snapshot",
    ),
    (["info", "--repair", "{log}", "-o", "{log}"], "-o"),
    (["calibrate", "validate", "{log}", "--calib", "{cal}", "-o", "{log}"], "-o"),
]


@pytest.mark.parametrize(("argv", "option"), SAME_AS_INPUT)
def test_an_input_or_a_file_of_another_kind_is_never_an_output(
    argv: list[str],
    option: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.chdir(tmp_path)
    files = _files(tmp_path)
    before = {k: _digest(p) for k, p in files.items()}
    assert main([a.format(**{k: str(p) for k, p in files.items()}) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f": {option} " in err, err
    assert {k: _digest(p) for k, p in files.items()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in files.values())


# (argv with {log}, {img}, {cal} for the inputs, {file} a file, {none} a missing folder;
# the option named): an output that cannot go where it is meant, refused before any work
# (the inputs are junk: any work would fail first on them); those made as folders (-o DIR
# of validate and sensitivity, --out of sim render) were once refused only after it, and
# the folders of sim log, sim rig and demo with exit 1 and "Not a directory"
BAD_FOLDER = [
    (["calibrate", "validate", "{log}", "--calib", "{cal}", "-o", "{file}/overlays"], "-o"),
    (["analyze", "sensitivity", "{log}", "--calib", "{cal}", "-o", "{file}/sens"], "-o"),
    (["sim", "render", "--out", "{file}/render"], "--out"),
    (["sim", "log", "board", "--out", "{file}/board"], "--out"),
    (["sim", "rig", "--out", "{file}/rig", "--duration", "1"], "--out"),
    (["demo", "--out", "{file}/demo", "--seconds", "1"], "--out"),
    (["export", "ros2", "{log}", "-o", "{file}/bag"], "-o"),
    (["colorize", "{log}", "--calib", "{cal}", "-o", "c.ply", "--preview", "{none}/p.png"],
     "--preview"),
    (["colorize", "{log}", "--calib", "{cal}", "-o", "{none}/c.ply"], "-o"),
    (["calibrate", "time-offset", "{log}", "--calib", "{cal}", "-o", "{none}/c.yaml"], "-o"),
    (["calibrate", "fisheye", "{img}", "--fov", "185", "-o", "c.yaml", "--overlay",
      "{file}/o.png"], "--overlay"),
    (["replay", "{log}", "--config-out", "{none}/r.yaml"], "--config-out"),
    (["info", "--repair", "{log}", "-o", "{file}/fixed.mcap"], "-o"),
]  # fmt: skip


@pytest.mark.parametrize(("argv", "option"), BAD_FOLDER)
def test_an_output_into_a_missing_folder_or_under_a_file_is_refused_before_the_work(
    argv: list[str], option: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    monkeypatch.chdir(tmp_path)
    files = _files(tmp_path)
    names = {k: str(p) for k, p in files.items()}
    names |= {"file": str(files["cal"]), "none": str(tmp_path / "nodir")}
    before = {k: _digest(p) for k, p in files.items()}
    assert main([a.format(**names) for a in argv]) == 2
    err = capsys.readouterr().err
    why = (
        f"{files['cal']} is a file, not a folder"
        if "{file}" in " ".join(argv)
        else f"the folder {tmp_path / 'nodir'} does not exist; create it first"
    )
    assert err.count("\n") == 1 and f": {option} " in err and err.endswith(f": {why}\n"), err
    assert {k: _digest(p) for k, p in files.items()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in files.values())


def test_the_line_names_the_output_and_the_input(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = _files(tmp_path)["log"]
    argv = ["calibrate", "extrinsic", str(log), "--intrinsics", str(tmp_path / "calib.yaml"),
            "--board", "9x7x0.1", "-o", str(log)]  # fmt: skip
    assert main(argv) == 2
    assert capsys.readouterr().err == (
        f"acq calibrate extrinsic: -o {log}: is the input LOG {log}; give another file\n"
    )
    # an existing log where a YAML goes, not an input: refused even with --force
    other = tmp_path / "other.mcap"
    other.write_bytes(log.read_bytes())
    argv = ["replay", str(log), "--config-out", str(other), "--force"]
    assert main(argv) == 2
    assert capsys.readouterr().err == (
        f"acq replay: --config-out {other}: exists and is an MCAP log, not a YAML file; "
        "not overwritten\n"
    )


def test_a_calibration_is_updated_in_place_only_with_force(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    files = _files(tmp_path)
    cal = files["cal"]
    text = cal.read_text()
    argv = ["calibrate", "time-offset", str(files["log"]), "--calib", str(cal), "-o", str(cal)]
    assert main(argv) == 2
    assert capsys.readouterr().err == (
        f"acq calibrate time-offset: -o {cal}: is the input --calib {cal}; --force updates it "
        "in place, keeping the old one as calib.yaml.bak\n"
    )
    assert cal.read_text() == text and not (tmp_path / "calib.yaml.bak").exists()
    # with --force the command runs (and stops at the log, which is none)
    assert main([*argv, "--force"]) == 2
    assert "--force" not in capsys.readouterr().err
    assert cal.read_text() == text and not (tmp_path / "calib.yaml.bak").exists()


def test_render_again_needs_force_and_keeps_the_old_calibration(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "r"
    out.mkdir()
    mine = "version: 1  # the rig's, edited by hand\n"
    (out / "calib.yaml").write_text(mine)
    argv = ["sim", "render", "--out", str(out), "--time", "1"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err == (
        f"acq sim render: --out {out / 'calib.yaml'}: exists; --force replaces it, keeping the "
        "old one as calib.yaml.bak\n"
    )
    assert sorted(p.name for p in out.iterdir()) == ["calib.yaml"]
    assert main([*argv, "--force"]) == 0
    assert (out / "calib.yaml.bak").read_text() == mine
    assert "version: 1" in (out / "calib.yaml").read_text() != mine
    assert f"kept the old {out / 'calib.yaml'} as {out / 'calib.yaml.bak'}" in (
        capsys.readouterr().err
    )
    # calibrate fisheye updates its CALIB in place (what its -o is for), keeping a backup
    rendered = (out / "calib.yaml").read_text()
    fisheye = ["calibrate", "fisheye", str(out / "frame.png"), "--fov", "185"]
    assert main([*fisheye, "-o", str(out / "calib.yaml")]) == 0
    assert (out / "calib.yaml.bak").read_text() == rendered != (out / "calib.yaml").read_text()


def test_demo_refuses_a_folder_it_did_not_write(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / ".recording").mkdir()
    (tmp_path / ".recording" / "mine.mcap").write_bytes(MCAP_MAGIC)
    (tmp_path / "calib.yaml").write_text("version: 1\n")
    before = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*"))
    assert main(["demo", "--out", str(tmp_path), "--seconds", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"acq demo: --out {tmp_path}: holds files and is not an earlier")
    assert err.count("\n") == 1
    assert sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*")) == before
    assert (tmp_path / "calib.yaml").read_text() == "version: 1\n"


def _small_log(path: Path, messages: int = 400) -> None:
    with path.open("wb") as f:
        w = Writer(f)
        w.start()
        schema = w.register_schema("raw", "octets", b"")
        channel = w.register_channel("/raw", "octets", schema)
        rng = random.Random(0)  # bytes that do not compress
        for i in range(messages):
            w.add_message(channel, i * 1000, rng.randbytes(1000), i * 1000)
        w.finish()


def _limit_file_size() -> None:
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails (EFBIG)
    resource.setrlimit(resource.RLIMIT_FSIZE, (50_000, 50_000))


def test_a_failed_repair_names_its_file_and_leaves_nothing(tmp_path: Path) -> None:
    log, out = tmp_path / "cut.mcap", tmp_path / "copy.mcap"
    _small_log(log)
    done = subprocess.run(
        [sys.executable, "-m", "acq.cli", "info", "--repair", str(log), "-o", str(out)],
        capture_output=True, text=True, preexec_fn=_limit_file_size, timeout=60,
    )  # fmt: skip
    assert done.returncode == 3  # a file size limit is a disk reserve's exit
    assert done.stderr.startswith(f"acq info: {out}: too large for the disk of {tmp_path} or ")
    assert len(done.stderr.splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cut.mcap"]


# (argv with {log}, {img}, {cal} and {out} for the existing product, its name in tmp_path)
PRODUCTS = [
    (["colorize", "{log}", "--calib", "{cal}", "-o", "{out}", "--no-preview"], "c.ply"),
    (["colorize", "{log}", "--calib", "{cal}", "-o", "c.las", "--preview", "{out}"], "p.png"),
    (
        [
            "probe",
            "camera",
            "--driver",
            "opencv",
            "--source",
            "http://127.0.0.1:9/x",
            "--snapshot",
            "{out}",
        ],
        "snap.jpg",
    ),
    (["analyze", "sensitivity", "{log}", "--calib", "{cal}", "-o", "{dir}"], "s/sensitivity.json"),
    (
        ["calibrate", "fisheye", "{img}", "--fov", "185", "-o", "c.yaml", "--overlay", "{out}"],
        "o.png",
    ),
    (
        ["calibrate", "validate", "{log}", "--calib", "{cal}", "-o", "{dir}"],
        "v/validate_overlay.png",
    ),
    (["sim", "render", "--out", "{dir}"], "r/frame.png"),
]


@pytest.mark.parametrize(("argv", "name"), PRODUCTS)
def test_a_product_acq_did_not_write_is_replaced_only_with_force(
    argv: list[str], name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A cloud, image or report that is not acq's (no mark: acq.provenance) is refused
    by name; one that acq wrote passes the check (the command then fails on its fake
    inputs, for another reason)."""
    from acq.provenance import marked_image

    files = _files(tmp_path)
    out = tmp_path / name
    out.parent.mkdir(exist_ok=True)
    foreign = {".ply": b"ply\nformat ascii 1.0\nend_header\n", ".json": b'{"mine": 1}\n'}
    out.write_bytes(foreign.get(out.suffix, b"\xff\xd8\xff\xe0" + bytes(64)))
    before = _digest(out)
    args = [a.format(**files, out=out, dir=out.parent) for a in argv]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert f"{out}: exists and was not written by acq; --force replaces it" in err, err
    assert _digest(out) == before
    mine = {".ply": b"ply\nformat ascii 1.0\ncomment acq 0.1.0\nend_header\n",
            ".json": b'{\n  "software": "acq 0.1.0"}\n'}  # fmt: skip
    out.write_bytes(mine.get(out.suffix, marked_image(b"\xff\xd8\xff\xe0\x00\x10" + bytes(64))))
    main(args)
    assert "not written by acq" not in capsys.readouterr().err


def test_an_existing_calibration_is_updated_not_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """time-offset and extrinsic update an existing -o that is not their input without
    --force (its other cameras are kept; the run here stops at the log, which is none);
    one of another laser is refused before any work, naming it; nothing is written."""
    from acq.camera import calibfile
    from acq.camera.calibfile import Calibration, CameraCalib
    from acq.geometry.transforms import Rigid
    from acq.sim.world import default_lens

    files = _files(tmp_path)
    log, cal, out = files["log"], files["cal"], tmp_path / "out.yaml"
    entry = CameraCalib(default_lens(), Rigid.identity())
    calibfile.save(Calibration(cameras={"camera": entry}), cal)
    calibfile.save(Calibration(cameras={"right": entry}), out)
    runs = [
        ["calibrate", "time-offset", str(log), "--calib", str(cal), "-o", str(out)],
        ["calibrate", "extrinsic", str(log), "--intrinsics", str(cal), "--board", "9x7x0.1",
         "-o", str(out)],
    ]  # fmt: skip
    for argv in runs:
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert "--force" not in err and str(out) not in err and "log" in err, err
    calibfile.save(Calibration(laser="other", cameras={"right": entry}), out)
    for argv in runs:
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.endswith(
            f": {out}: its cameras are calibrated against laser 'other', these against "
            "'laser'; give another file\n"
        ), err
    assert not (tmp_path / "out.yaml.bak").exists()
