"""The colorize report's text and JSON: per camera, and the colour balance."""

from __future__ import annotations

import json
from dataclasses import asdict
from typing import Any

from acq.cloud.report import Report


def _report(**kw: Any) -> Report:
    return Report(output="c.ply", points=1000, coloured=950, scans=10, **kw)


def test_each_camera_has_its_points_share_and_frames() -> None:
    cams = {
        "left": {"points": 600, "frames_used": 120, "frames": 150},
        "right": {"points": 350, "frames_used": 98},
    }
    lines = _report(cameras=cams).lines()
    assert "camera left: 600 points (60.0 %) from 120 of 150 frames" in lines
    assert "camera right: 350 points (35.0 %) from 98 frames" in lines


def test_the_balance_shows_pairs_and_each_cameras_gains() -> None:
    balance = {
        "applied": True,
        "pairs": 12345,
        "cameras": {
            "left": {"pairs": 9000, "r": [0.9, 1.0, 1.1], "g": [0.95, 1.0, 1.05], "b": [1, 1, 1]},
            "right": {"pairs": 8000, "r": [1.2, 1.25, 1.3], "g": [1, 1, 1], "b": [0.8, 0.85, 0.9]},
        },
    }
    lines = _report(balance=balance).lines()
    i = lines.index("colour balance from 12,345 point pairs (gains min/median/max)")
    assert (
        lines[i + 1] == "  left: R 0.90/1.00/1.10  G 0.95/1.00/1.05  B 1.00/1.00/1.00 (9,000 pairs)"
    )
    assert (
        lines[i + 2]
        == "  right: R 1.20/1.25/1.30  G 1.00/1.00/1.00  B 0.80/0.85/0.90 (8,000 pairs)"
    )


def test_balance_off_is_one_line_and_none_is_no_line() -> None:
    off = _report(balance={"applied": False}).lines()
    assert [x for x in off if "balance" in x] == ["colour balance: off (--no-balance)"]
    assert not [x for x in _report().lines() if "balance" in x or x.startswith("camera ")]


def test_the_json_report_carries_cameras_and_balance() -> None:
    cams = {"left": {"points": 600, "frames_used": 120}}
    balance = {"applied": True, "pairs": 5, "cameras": {"left": {"r": [1.0, 1.0, 1.0]}}}
    back = json.loads(json.dumps(asdict(_report(cameras=cams, balance=balance))))
    assert back["cameras"] == cams
    assert back["balance"] == balance
