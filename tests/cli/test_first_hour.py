"""What a new user meets first: a wrong combination of options refused before the work
starts, help texts that point to what exists, scripts that answer --help."""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from acq.camera import calibfile
from acq.cli.main import build_parser
from acq.cli.main import main as acq_main
from acq.sim.drive_log import write_drive_log
from tests.conftest import once_per_run

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


# Runs each script with --help in a process of its own, forked from one that has already
# imported what the scripts import at their top (their --help's whole cost, about 1 s a
# script when each starts a Python of its own); only a speed-up, so a module of that list
# that is gone is passed over. argv: the JSON list of the runs.
_FORKS = """
import contextlib, importlib, json, os, runpy, sys, traceback
for name in ("numpy", "scipy.optimize", "cv2", "numba", "acq.log", "acq.cloud.colorize",
             "acq.calib.validate", "acq.calib.board_pose", "acq.calib.time_offset",
             "acq.sim.demo"):
    with contextlib.suppress(ImportError):
        importlib.import_module(name)
codes = {}
for run in json.loads(sys.argv[1]):
    sys.stdout.flush(), sys.stderr.flush()
    pid = os.fork()
    if pid == 0:
        code = 1
        try:
            os.chdir(run["cwd"])
            for fd, path in ((1, run["stdout"]), (2, run["stderr"])):
                os.dup2(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC), fd)
            script = run["target"].endswith(".py")
            sys.argv = [run["target"], "--help"]
            sys.path[0] = os.path.dirname(run["target"]) if script else os.getcwd()
            try:
                if script:
                    runpy.run_path(run["target"], run_name="__main__")
                else:
                    runpy.run_module(run["target"], run_name="__main__", alter_sys=True)
                code = 0
            except SystemExit as e:
                code = e.code if isinstance(e.code, int) else (e.code is not None)
                if isinstance(e.code, str):
                    print(e.code, file=sys.stderr)
        except BaseException:
            traceback.print_exc()
        finally:
            sys.stdout.flush(), sys.stderr.flush()
            os._exit(code)
    codes[run["target"]] = os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])
print(json.dumps(codes))
"""


def _run_helps(folder: Path) -> dict[str, Any]:
    """Every script of _readme_scripts() run with --help (_FORKS), each in an empty
    folder of its own: its exit status, stdout, stderr and what it left there."""
    runs = []
    for i, (*_, target) in enumerate(_readme_scripts()):
        (cwd := folder / str(i)).mkdir()
        path = str(REPO / target) if target.endswith(".py") else target
        runs.append({"target": path, "cwd": str(cwd), "stdout": str(folder / f"{i}.out"),
                     "stderr": str(folder / f"{i}.err")})  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run([sys.executable, "-c", _FORKS, json.dumps(runs)], cwd=folder,
                          env=env, capture_output=True, text=True, timeout=600)  # fmt: skip
    assert done.returncode == 0, done.stderr
    codes = json.loads(done.stdout)
    return {
        " ".join(script): {
            "code": codes[run["target"]],
            "stdout": Path(run["stdout"]).read_text(),
            "stderr": Path(run["stderr"]).read_text(),
            "left": sorted(p.name for p in Path(run["cwd"]).iterdir()),
        }
        for script, run in zip(_readme_scripts(), runs, strict=True)
    }


@pytest.fixture(scope="module")
def helps(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    return once_per_run(tmp_path_factory, "readme_script_helps", _run_helps)[1]


@pytest.mark.parametrize("script", _readme_scripts(), ids=" ".join)
def test_every_script_the_readme_names_answers_help(
    script: list[str], helps: dict[str, Any]
) -> None:
    """Each answers --help with its usage, writing nothing (a script that took --help for
    its output folder once made one named so)."""
    run = helps[" ".join(script)]
    assert run["code"] == 0 and run["stdout"].startswith("usage:"), run["stderr"]
    assert not run["left"]


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
