"""The README's picture of the live swath: what a Foxglove WebSocket client of ``acq record
--live`` receives on ``/live/swath`` after the simulated rig has driven a while.

It starts ``acq sim rig`` (or takes a running rig's ``-c rig.yaml``), records it with
``--live`` for ``--seconds``, keeps every swath a client receives, and draws the last one
(the street of the last ``--live-swath-s`` seconds, placed with the rig's odometry): from
above, and the left side of the street seen from it. One JSON line: the swaths received,
their points and rate, the picture's path.

Run as a script: ``python bench/live_swath.py [--png docs/live_swath.png] [--seconds S]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from live import Client, _line, record, start_rig
from processes import Procs, free_port, workdir

SWATH = "/live/swath"


def swath_points(msg: Any) -> tuple[np.ndarray, np.ndarray]:
    """A swath's xyz (N,3) m and rgb (N,3) uint8."""
    raw = np.frombuffer(msg.data, np.uint8).reshape(-1, msg.point_stride)
    return raw[:, :12].copy().view("<f4").astype(np.float64), raw[:, 12:15]


def _panel(u: np.ndarray, v: np.ndarray, depth: np.ndarray, rgb: np.ndarray,
           res: float) -> np.ndarray:  # fmt: skip
    """Points at (u right, v up) m drawn at ``res`` m/px, the smallest ``depth`` winning
    each pixel, 2x2 px each; BGR, grey where none."""
    cols = ((u - u.min()) / res).astype(int)
    rows = ((v.max() - v) / res).astype(int)
    img = np.full((rows.max() + 2, cols.max() + 2, 3), 40, np.uint8)
    order = np.argsort(-depth)  # the nearest written last: it wins
    for dr in (0, 1):
        for dc in (0, 1):
            img[rows[order] + dr, cols[order] + dc] = rgb[order][:, ::-1]
    return img


def _caption(img: np.ndarray, text: str) -> np.ndarray:
    band = np.full((36, img.shape[1], 3), 255, np.uint8)
    cv2.putText(band, text, (8, 25), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([band, img])


def draw(xyz: np.ndarray, rgb: np.ndarray, res: float = 0.1, half_width_m: float = 14.0
         ) -> np.ndarray:  # fmt: skip
    """From above (the highest point winning; ``half_width_m`` either side of the track),
    then the street's left side seen from the track (the nearest point winning); the
    drive runs to the right."""
    along = xyz[:, 0] - xyz[:, 0].min()
    bins = (along // 2).astype(int)  # the track's side offset: the median y, every 2 m
    centre = np.zeros(bins.max() + 1)
    for b in np.unique(bins):
        centre[b] = np.median(xyz[bins == b, 1])
    across = xyz[:, 1] - centre[bins]
    near = np.abs(across) < half_width_m
    top = _panel(along[near], across[near], -xyz[near, 2], rgb[near], res)
    left = across > 0.5
    side = _panel(along[left], xyz[left, 2], across[left], rgb[left], res)
    width = max(top.shape[1], side.shape[1])
    span = float(np.ptp(along))
    top = _caption(
        np.pad(top, ((0, 0), (0, width - top.shape[1]), (0, 0))),
        f"/live/swath from above: the last {span:.0f} m of the drive, left side up",
    )
    side = _caption(np.pad(side, ((0, 0), (0, width - side.shape[1]), (0, 0))),
                    "its left side seen from the street")  # fmt: skip
    return np.vstack([top, side])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("-c", "--config", type=Path, help="a running rig's rig.yaml")
    p.add_argument("--seconds", type=float, default=45.0, help="recording, s (default 45)")
    p.add_argument("--swath-s", type=float, default=30.0, help="--live-swath-s (default 30)")
    p.add_argument("--png", type=Path, default=Path("live_swath.png"), help="the picture")
    p.add_argument("--prerender", type=float, default=60.0, help="acq sim rig --prerender S")
    args = p.parse_args()
    with workdir("live-swath", keep=False) as work:
        procs = Procs()
        try:
            config = args.config or start_rig(procs, work, args.prerender, sys.stderr)
            port = free_port()
            run = record(
                procs, config, work / "logs", port, ["--live-swath-s", f"{args.swath_s:g}"]
            )
            client = Client(port, {SWATH})
            time.sleep(args.seconds)
            client.close()
            run.stop()
        finally:
            procs.close()
    got = client.seen.messages.get(SWATH, [])
    if not got:
        _line("live_swath", swaths=0, closed=client.closed)
        sys.exit(1)
    xyz, rgb = swath_points(got[-1][1])
    picture = draw(xyz, rgb)
    cv2.imwrite(str(args.png), picture)
    times = np.array([t for t, _ in got])
    _line(
        "live_swath", swaths=len(got), rate_hz=round((len(got) - 1) / float(np.ptp(times)), 2),
        points_last=int(xyz.shape[0]), frame_id=got[-1][1].frame_id,
        extent_m=np.ptp(xyz, axis=0).round(1).tolist(), png=str(args.png),
        picture_px=[int(picture.shape[1]), int(picture.shape[0])],
    )  # fmt: skip


if __name__ == "__main__":
    main()
