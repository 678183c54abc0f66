"""Every numeric option of every command is range-checked while the command line is
parsed: a bad value is one line naming the option and its range, exit status 2, and the
command never runs."""

from __future__ import annotations

import argparse
import contextlib
import functools
import io
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from acq.cli import (
    analyze,
    calibrate_extrinsic,
    calibrate_fisheye,
    calibrate_time_offset,
    calibrate_validate,
    colorize,
    demo,
    main,
    probe,
    record,
    replay,
    sim,
    sim_logs,
    view,
)
from acq.cli.main import build_parser
from acq.cli.option_types import Number

# what each command needs besides the option tried (the files need not exist: only parsed)
BASE: dict[tuple[str, ...], list[str]] = {
    ("demo",): [],
    ("sim", "render"): ["--out", "x"],
    ("sim", "scanner"): ["--model", "utm-30lx"],
    ("sim", "camera"): [],
    ("sim", "log"): ["validation", "--out", "x"],
    ("sim", "rig"): [],
    ("probe", "scanner"): ["--driver", "hokuyo", "--url", "socket://127.0.0.1:1"],
    ("probe", "camera"): ["--driver", "opencv", "--source", "0"],
    ("record",): [],
    ("replay",): ["x.mcap"],
    ("colorize",): ["x.mcap", "--calib", "c.yaml", "-o", "x.ply"],
    ("mesh",): ["x.mcap", "--calib", "c.yaml", "-o", "m.glb"],
    ("calibrate", "fisheye"): ["i.png", "--fov", "185", "-o", "c.yaml"],
    ("calibrate", "extrinsic"): [
        "x.mcap",
        "--intrinsics",
        "c.yaml",
        "--board",
        "9x7",
        "-o",
        "o.yaml",
    ],
    ("calibrate", "time-offset"): ["x.mcap", "--calib", "c.yaml", "-o", "o.yaml"],
    ("calibrate", "check"): ["x.mcap", "--calib", "c.yaml"],
    ("analyze", "sensitivity"): ["x.mcap", "--calib", "c.yaml"],
    ("status",): [],
    ("view",): ["x.ply"],
}


def _walk(
    parser: argparse.ArgumentParser, path: tuple[str, ...] = ()
) -> Iterator[tuple[tuple[str, ...], argparse.Action]]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, child in action.choices.items():
                yield from _walk(child, (*path, name))
        else:
            yield path, action


@functools.cache
def _parser() -> argparse.ArgumentParser:
    return build_parser()


def _numeric() -> list[tuple[tuple[str, ...], argparse.Action]]:
    """(command path, action) of every option taking a number (or NAME=number)."""
    return [(p, a) for p, a in _walk(_parser()) if isinstance(a.type, Number) or a.dest == "sigma"]


def test_every_numeric_option_has_a_range() -> None:
    bare = [(p, a.option_strings) for p, a in _walk(_parser()) if a.type in (int, float)]
    assert bare == []
    found = {(" ".join(p), a.option_strings[-1]) for p, a in _numeric()}
    expected = {("colorize", "--chunk"), ("colorize", "--workers"), ("record", "--duration"),
                ("colorize", "--time-offset"), ("calibrate time-offset", "--search"),
                ("probe scanner", "--timeout"), ("analyze sensitivity", "--sigma"),
                ("sim scanner", "--drift-ppm"), ("replay", "--speed")}  # fmt: skip
    assert expected <= found
    assert {p for p, _ in _numeric()} <= set(BASE)


def _no_run(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Every command's handler replaced by one that notes it ran: a value the parser lets
    through would run it."""
    ran: list[str] = []
    handlers = {
        demo: ["run"], record: ["run"], replay: ["run"], colorize: ["run"],
        probe: ["run_scanner", "run_camera"], analyze: ["run_sensitivity"],
        sim: ["run_render", "run_scanner", "run_camera", "run_rig"], sim_logs: ["run_log"],
        calibrate_fisheye: ["run_fisheye"], calibrate_extrinsic: ["run_extrinsic"],
        calibrate_time_offset: ["run_time_offset"], calibrate_validate: ["run_validate"],
        view: ["run"],
    }  # fmt: skip
    for module, names in handlers.items():
        for name in names:
            monkeypatch.setattr(module, name, lambda args, n=name: ran.append(n) or 0)
    return ran


@pytest.mark.parametrize(
    ("path", "option", "value"),
    [
        (("record",), "--duration", "nan"),
        (("record",), "--duration", "inf"),
        (("record",), "--duration", "-1"),
        (("record",), "--duration", "0"),
        (("colorize",), "--chunk", "0"),
        (("colorize",), "--chunk", "-1"),
        (("colorize",), "--chunk", "1e-9"),
        (("colorize",), "--chunk", "NaN"),
        (("colorize",), "--workers", "0"),
        (("colorize",), "--workers", "-1"),
        (("colorize",), "--time-offset", "1e30"),
        (("colorize",), "--time-offset", "nan"),
        (("colorize",), "--max-dt", "nan"),
        (("calibrate", "time-offset"), "--search", "-1"),
        (("calibrate", "time-offset"), "--search", "nan"),
        (("probe", "scanner"), "--timeout", "-1"),
        (("probe", "camera"), "--fps", "inf"),
        (("replay",), "--speed", "1e-300"),
        (("analyze", "sensitivity"), "--sigma", "yaw=1e300"),
        (("calibrate", "extrinsic"), "--pupil-shift", "nan"),
        (("sim", "render"), "--time", "inf"),
        (("demo",), "--seconds", "nan"),
        (("sim", "log"), "--seconds", "nan"),
        (("sim", "log"), "--cameras", "3"),
        (("view",), "--port", "nan"),
        (("view",), "--port", "65536"),
    ],
)
def test_a_bad_value_is_one_line_and_exit_2(
    path: tuple[str, ...],
    option: str,
    value: str,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
) -> None:
    monkeypatch.chdir(tmp_path)
    ran = _no_run(monkeypatch)
    assert main([*path, *BASE[path], option, value]) == 2
    err = capsys.readouterr().err
    assert ran == [] and err.count("\n") == 1, err
    assert err.startswith(f"acq {' '.join(path)}: argument {option}: expected "), err
    assert "[" in err or "(" in err, err


# texts to try for any number: the odd ones, then whatever hypothesis makes
ODD = ["nan", "NaN", "-nan", "inf", "-inf", "Infinity", "-0", "-0.0", "0", "1e308", "-1e308",
       "1e-320", "9" * 400, "-" + "9" * 400, "9" * 5000, "", " ", "1_000", "0x10", "1,5",
       "١٢", "3.0", "2**8", "auto", "None", "\u00b2", "1e", "--1"]  # fmt: skip
texts = st.one_of(
    st.sampled_from(ODD),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-(10**40), 10**40).map(str),
    st.text(max_size=12),
)


@given(st.data())
@settings(max_examples=400, deadline=None)
def test_any_text_parses_in_range_or_is_refused_naming_the_option(data: st.DataObject) -> None:
    path, action = data.draw(st.sampled_from(_numeric()))
    text = data.draw(texts)
    option = action.option_strings[-1]
    value = f"yaw={text}" if action.dest == "sigma" else text
    argv = [*path, *BASE[path], f"{option}={value}"]
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        try:
            args = _parser().parse_args(argv)
        except SystemExit as e:
            assert e.code == 2
            line = err.getvalue()
            assert line.count("\n") == 1 and f"argument {option}" in line, (argv, line)
            return
    got = getattr(args, action.dest)
    if action.dest == "sigma":
        assert analyze.SIGMA.contains(got[-1][1]), (argv, got)
    else:
        assert isinstance(action.type, Number) and action.type.contains(got), (argv, got)
