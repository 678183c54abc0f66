"""bench/partial_decode.py: its need figures from known marks, and one line saying why
when the system libjpeg-turbo is absent."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from tests.bench_scripts import load


def test_need_counts_imcu_rows_the_rows_to_the_last_and_the_box() -> None:
    bench = load("partial_decode")
    import jpeg_partial  # bench/'s, as the script imports it (load put bench/ on the path)

    header = jpeg_partial.Header(width=64, height=64, imcu_rows=16)
    rows = np.zeros(64, dtype=bool)
    rows[[0, 40, 41]] = True  # iMCU rows 0 and 2 of 4
    none = np.zeros(64, dtype=bool)
    blocks = np.zeros((4, 4), dtype=bool)
    blocks[0, 1] = True
    got = bench.need([(b"", header, rows, 8, 24, blocks), (b"", header, none, 64, 0, blocks)])
    assert got["frames"] == 2
    assert got["imcu_rows"]["mean"] == pytest.approx(0.25)  # 0.5 and 0
    assert got["to_last"]["mean"] == pytest.approx(0.375)  # 3/4 and 0
    assert got["box"]["mean"] == pytest.approx(42 * 16 / 4096 / 2, abs=1e-4)
    assert got["blocks16"]["median"] == pytest.approx(1 / 16)


def test_without_the_library_one_line_says_why_and_exits_0(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    bench = load("partial_decode")
    import jpeg_partial

    monkeypatch.setattr(jpeg_partial, "available", lambda: False)
    monkeypatch.setattr(jpeg_partial, "why_unavailable", lambda: "no system libjpeg (here)")
    monkeypatch.setattr(sys, "argv", ["partial_decode.py"])
    bench.main()  # returns: exit status 0
    [line] = capsys.readouterr().out.splitlines()
    assert json.loads(line) == {
        "bench": "partial_decode", "figure": "skipped", "why": "no system libjpeg (here)",
    }  # fmt: skip
