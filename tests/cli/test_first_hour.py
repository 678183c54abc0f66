"""What a new user meets first: a wrong combination of options refused before the work
starts, help texts that point to what exists, scripts that answer --help."""

from __future__ import annotations

import argparse
import os
import re
import shlex
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from acq.camera import calibfile
from acq.cli.main import build_parser
from acq.cli.main import main as acq_main
from acq.sim.drive_log import write_drive_log

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> tuple[list[str], Path, list[str], Path]:
    """A short drive without odometry and one with, each with its calib.yaml."""
    d = tmp_path_factory.mktemp("drives")
    bare = write_drive_log(d / "bare", 0.3, odometry_hz=0.0)
    moving = write_drive_log(d / "moving", 0.3)
    calib = d / "calib.yaml"
    calibfile.save(bare.calibration, calib)
    return list(map(str, bare.files)), calib, list(map(str, moving.files)), calib


def test_view_best_without_a_trajectory_is_bad_input_before_any_chunk(
    drive: tuple[list[str], Path, list[str], Path], tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    bare, calib, moving, _ = drive
    out = tmp_path / "c.ply"
    argv = ["colorize", *bare, "--calib", str(calib), "-o", str(out), "--view", "best"]
    assert acq_main(argv) == 2
    err = capsys.readouterr().err
    assert err == (
        "acq colorize: --view best needs a trajectory (CAN odometry or GNSS fixes in the "
        "log, or --trajectory CSV) and motion compensation; use --view nearest\n"
    ), err
    assert not out.exists() and not list(tmp_path.iterdir())
    argv = ["colorize", *moving, "--calib", str(calib), "-o", str(out), "--view", "best",
            "--no-motion-compensation"]  # fmt: skip
    assert acq_main(argv) == 2
    err = capsys.readouterr().err
    assert err == (
        "acq colorize: --view best needs motion compensation: drop "
        "--no-motion-compensation, or use --view nearest\n"
    ), err
    assert not list(tmp_path.iterdir())


def _helps(parser: argparse.ArgumentParser) -> Iterator[tuple[str, str]]:
    """(command, text) of every description and option help under ``parser``."""
    yield parser.prog, parser.description or ""
    for action in parser._actions:
        yield parser.prog, str(action.help or "")
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                yield from _helps(child)


def test_every_file_a_help_text_names_exists() -> None:
    named = [
        (prog, m.group(0))
        for prog, text in _helps(build_parser())
        for m in re.finditer(r"\b(?:acq|sim|drivers|bench|config|systemd)/[\w/.-]+\.\w+", text)
    ]
    missing = [(prog, path) for prog, path in named if not (REPO / path).exists()]
    assert not missing, missing


def _pages() -> list[Path]:
    """README.md and the documentation's pages."""
    return [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]


def _readme_scripts() -> list[list[str]]:
    """The `python -m MODULE` and `python bench/NAME.py` commands README.md and the
    documentation name."""
    text = "\n".join(page.read_text() for page in _pages())
    found = re.findall(r"python (-m [\w.]+|bench/\w+\.py)", text)
    return [f.split() for f in dict.fromkeys(found)]


@pytest.mark.parametrize("script", _readme_scripts(), ids=" ".join)
def test_every_script_the_readme_names_answers_help(script: list[str], tmp_path: Path) -> None:
    """Each answers --help with its usage, writing nothing (a script that took --help for
    its output folder once made one named so)."""
    *options, target = script  # ["-m", MODULE] or [bench/NAME.py]
    path = str(REPO / target) if target.endswith(".py") else target
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    run = subprocess.run([sys.executable, *options, path, "--help"], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert run.returncode == 0 and run.stdout.startswith("usage:"), run.stderr
    assert not list(tmp_path.iterdir())


def test_sim_log_writes_a_recording_and_the_command_to_try_on_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "v"
    assert acq_main(["sim", "log", "validation", "--out", str(out), "--seconds", "0.3"]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[-1].startswith("try: acq calibrate validate "), printed
    assert (out / "calib.yaml").exists() and list(out.glob("*.mcap"))
    assert acq_main(shlex.split(printed[-1].removeprefix("try: acq "))) == 0
    assert "right colour" in capsys.readouterr().out
    before = sorted(out.iterdir())
    assert acq_main(["sim", "log", "board", "--out", str(out)]) == 2  # not empty: refused
    assert capsys.readouterr().err == (
        f"acq sim log: --out {out}: not empty; give a new or empty folder\n"
    )
    assert sorted(out.iterdir()) == before


def test_readme_code_fences_stand_on_their_own_lines() -> None:
    """A fence with text after it (```` ``` `--crs` is ...````) swallows the prose that
    follows into the code block."""
    for page in _pages():
        lines = page.read_text().splitlines()
        fences = [(n, s) for n, s in enumerate(lines, 1) if "```" in s]
        # a language, or attributes: ```{.sh .runnable}
        bad = [
            (n, s) for n, s in fences if not re.fullmatch(r"```([\w-]*|\{[.\w -]+\})", s.strip())
        ]
        assert not bad, (page, bad)
        assert len(fences) % 2 == 0, page
