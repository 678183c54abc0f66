"""The live coloured scans of a log against ``acq colorize``'s: one JSON line.

The log is one recorded with ``acq record --log-colored`` (``/<laser>/colored``:
``foxglove.PointCloud`` in the laser frame, one per scan, stamped with the scan's stamp).
The same log is coloured offline with ``acq colorize LOG --calib CALIB --frame laser
--view nearest -o OUT.ply`` (every point in the laser frame, with its scan index and a
``coloured`` flag). Points are matched by scan (the offline scan index is the scan's
place among the log's ``/<laser>/scan`` stamps, the live cloud's stamp is the scan's) and
beam (the step of the point's bearing, from the ``device.<laser>`` geometry); a matched
pair whose ranges differ by more than 1 cm is counted apart (``range_mismatch``), not
matched. Figures: ``colour_within`` the share of the points coloured both ways whose
colours lie within 24/255 in every channel (target at least 0.95); ``coloured_live`` the
share of the offline-coloured points coloured live (target at least 0.95), and the same
within the scans the live colourer published (``coloured_live_in_live_scans``: what
skipped scans, and those at the start and end of the recording, do not lower). A live
point is coloured unless its alpha is 0. ``--no-balance`` colours offline without
evening out the cameras' exposure (the live colourer does not).

    python bench/live_agreement.py LOG [LOG ...] --calib CALIB [--offline OUT.ply]
    python bench/live_agreement.py [--seconds S]

Without LOG, ``acq sim rig`` is started and recorded for ``--seconds`` with
``--log-colored`` (``present`` false when ``acq record`` has no such option yet).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from processes import acq_command, workdir

from acq.cloud.ply import PLY_DTYPE
from acq.log.reader import LogReader, read_metadata

TOLERANCE = 24  # of 255, per channel
TARGET = 0.95
RANGE_TOLERANCE_M = 0.01

# foxglove.PackedElementField.NumericType -> numpy
_NUMERIC = {1: "u1", 2: "i1", 3: "<u2", 4: "<i2", 5: "<u4", 6: "<i4", 7: "<f4", 8: "<f8"}


@dataclass(frozen=True)
class Points:
    """Points of many scans: ``scan`` (N,) the scan's index in the log, ``xyz`` (N,3) m in
    the laser frame, ``rgb`` (N,3) uint8, ``coloured`` (N,) bool."""

    scan: np.ndarray
    xyz: np.ndarray
    rgb: np.ndarray
    coloured: np.ndarray


def cloud_fields(msg: Any) -> dict[str, np.ndarray]:
    """The per-point fields of a ``foxglove.PointCloud``, by name (packed ``rgb`` or
    ``rgba`` as uint32 like the others)."""
    dtype = np.dtype(
        {
            "names": [f.name for f in msg.fields],
            "formats": [_NUMERIC[f.type] for f in msg.fields],
            "offsets": [f.offset for f in msg.fields],
            "itemsize": msg.point_stride,
        }
    )
    a = np.frombuffer(msg.data, dtype=dtype, count=len(msg.data) // msg.point_stride)
    return {name: a[name] for name in dtype.names or ()}


def cloud_colours(f: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """((N,3) uint8 RGB, (N,) coloured) of a cloud's fields: ``red``, ``green``, ``blue``
    (and ``alpha``, 0: not coloured) or packed ``rgba`` (0xRRGGBBAA) or ``rgb``
    (0x00RRGGBB, every point coloured)."""
    if "red" in f:
        rgb = np.stack([f["red"], f["green"], f["blue"]], axis=1).astype(np.uint8)
        alpha = f.get("alpha")
        return rgb, np.ones(len(rgb), bool) if alpha is None else alpha > 0
    if "rgba" in f:
        v = f["rgba"].astype(np.uint32)
        rgb = np.stack([v >> 24, v >> 16, v >> 8], axis=1).astype(np.uint8)
        return rgb, (v & 0xFF) > 0
    v = f["rgb"].astype(np.uint32)
    rgb = np.stack([v >> 16, v >> 8, v], axis=1).astype(np.uint8)
    return rgb, np.ones(len(v), bool)


def read_live(files: list[Path], laser: str) -> tuple[Points, int]:
    """The log's live coloured points (scans numbered by their place among the log's
    ``/<laser>/scan`` stamps) and the number of coloured scans whose stamp is no scan's."""
    scans, clouds = [], []
    for path in files:
        reader = LogReader(path)
        for schema, channel, message in reader.messages():
            if channel.topic == f"/{laser}/scan":
                m = reader.decode(schema, channel, message)
                scans.append(m.timestamp.seconds * 10**9 + m.timestamp.nanos)
            elif channel.topic == f"/{laser}/colored":
                clouds.append(reader.decode(schema, channel, message))
    stamps = np.unique(np.array(scans, dtype=np.int64))
    parts: list[tuple[int, dict[str, np.ndarray]]] = []
    orphans = 0
    for c in clouds:
        t = c.timestamp.seconds * 10**9 + c.timestamp.nanos
        k = int(np.searchsorted(stamps, t))
        if k == stamps.size or stamps[k] != t:
            orphans += 1
            continue
        parts.append((k, cloud_fields(c)))
    scan = np.concatenate([np.full(len(f["x"]), k) for k, f in parts] or [np.zeros(0, int)])
    if not parts:
        return Points(scan, np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros(0, bool)), 0
    xyz = np.concatenate([np.stack([f["x"], f["y"], f["z"]], axis=1) for _, f in parts])
    colours = [cloud_colours(f) for _, f in parts]
    rgb = np.concatenate([c[0] for c in colours])
    coloured = np.concatenate([c[1] for c in colours])
    return Points(scan, xyz.astype(np.float64), rgb, coloured), orphans


def read_ply(path: Path) -> Points:
    """The points of a PLY that ``acq colorize`` wrote."""
    data = path.read_bytes()
    start = data.index(b"end_header\n") + len(b"end_header\n")
    v = np.frombuffer(data, dtype=PLY_DTYPE, offset=start)
    return Points(
        scan=v["scalar_scan"].astype(np.int64),
        xyz=np.stack([v["x"], v["y"], v["z"]], axis=1),
        rgb=np.stack([v["red"], v["green"], v["blue"]], axis=1),
        coloured=v["scalar_coloured"] > 0,
    )


def beam_keys(p: Points, geometry: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """(a key per point: scan x points per scan + beam step; its range, m)."""
    n = int(geometry["n_points"])
    bearing = np.arctan2(p.xyz[:, 1], p.xyz[:, 0])
    step = np.rint((bearing - geometry["angle_min"]) / geometry["angle_increment"]).astype(np.int64)
    step %= round(2 * np.pi / geometry["angle_increment"])  # bearings wrap at +-pi
    return p.scan * n + step, np.hypot(p.xyz[:, 0], p.xyz[:, 1])


def agreement(live: Points, offline: Points, geometry: dict[str, Any]) -> dict[str, Any]:
    """The live points against the offline ones: the figures of the module's docstring."""
    lk, lr = beam_keys(live, geometry)
    ok, orr = beam_keys(offline, geometry)
    _, li, oi = np.intersect1d(lk, ok, assume_unique=False, return_indices=True)
    same = np.abs(lr[li] - orr[oi]) <= RANGE_TOLERANCE_M
    li, oi = li[same], oi[same]
    both = live.coloured[li] & offline.coloured[oi]
    diff = np.abs(live.rgb[li[both]].astype(int) - offline.rgb[oi[both]].astype(int)).max(axis=1)
    off_coloured = int(offline.coloured.sum())
    in_live = offline.coloured & np.isin(offline.scan, live.scan)
    within = float((diff <= TOLERANCE).mean()) if diff.size else None
    share = int(both.sum()) / off_coloured if off_coloured else None
    return {
        "live_scans": int(np.unique(live.scan).size),
        "offline_scans": int(np.unique(offline.scan).size),
        "live_points": int(live.scan.size),
        "offline_points": int(offline.scan.size),
        "offline_coloured": off_coloured,
        "matched": int(li.size),
        "range_mismatch": int((~same).sum()),
        "coloured_both": int(both.sum()),
        "colour_within": None if within is None else round(within, 4),
        "coloured_live": None if share is None else round(share, 4),
        "coloured_live_in_live_scans": round(int(both.sum()) / max(int(in_live.sum()), 1), 4),
        "median_channel_diff": float(np.median(diff)) if diff.size else None,
        "ok": within is not None and share is not None and within >= TARGET and share >= TARGET,
    }


def colorize(logs: list[Path], calib: Path, out: Path, *options: str) -> list[str]:
    """``acq colorize LOGS --calib CALIB --frame laser --view nearest -o OUT [options]``:
    the command."""
    cmd = [*acq_command(), "colorize", *map(str, logs), "--calib", str(calib), "--frame",
           "laser", "--view", "nearest", "-o", str(out), "--no-preview", "--force"]  # fmt: skip
    cmd += options
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return ["acq", *cmd[len(acq_command()) :]]


def record_rig(work: Path, seconds: float) -> tuple[list[Path], Path]:
    """``acq sim rig`` recorded for ``seconds`` (with ``--log-colored`` when ``acq record``
    has it): (the log's files, the rig's calib.yaml)."""
    from live import record, start_rig
    from processes import Procs

    help_text = subprocess.run([*acq_command(), "record", "--help"], capture_output=True,
                               text=True, check=True).stdout  # fmt: skip
    extra = ["--log-colored"] if "--log-colored" in help_text else []
    procs = Procs()
    with (work / "sim.log").open("w") as err:
        try:
            config = start_rig(procs, work, seconds + 10.0, err)
            run = record(procs, config, work / "log", None, extra)
            run.sleep_until(seconds)
            run.stop()
            calib = config.with_name("calib.yaml")
            kept = work / "calib.yaml"
            kept.write_bytes(calib.read_bytes())  # the rig removes its files when it stops
        finally:
            procs.close()
    return run.files(), kept


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("logs", nargs="*", type=Path, metavar="LOG", help="the session's files "
                    "(default: a recording of acq sim rig made now)")  # fmt: skip
    ap.add_argument("--calib", type=Path, help="the rig's calib.yaml (required with LOG)")
    ap.add_argument("--seconds", type=float, default=20.0, help="without LOG: the recording")
    ap.add_argument("--laser", default="laser", help="the scanner's name (default laser)")
    ap.add_argument("--keep", action="store_true", help="without LOG: keep the recording")
    ap.add_argument("--no-balance", action="store_true", help="acq colorize --no-balance")
    ap.add_argument("--offline", type=Path, help="an acq colorize PLY already made of LOG "
                    "with --frame laser --view nearest (default: made now)")  # fmt: skip
    args = ap.parse_args()
    if args.logs and args.calib is None:
        ap.error("--calib is required with LOG")
    with workdir("live-agreement-", args.keep) as work:
        if not args.logs:
            args.logs, args.calib = record_rig(work, args.seconds)
        report(args)


def report(args: argparse.Namespace) -> None:
    """The JSON line for ``args``' log."""
    files = sorted(p for a in args.logs for p in (sorted(a.glob("*.mcap")) if a.is_dir() else [a]))
    geometry = json.loads(read_metadata(files[0])[f"device.{args.laser}"]["geometry"])
    live, orphans = read_live(files, args.laser)
    line = {"bench": "live_agreement", "topic": f"/{args.laser}/colored",
            "present": bool(live.scan.size), "orphan_clouds": orphans}  # fmt: skip
    if not live.scan.size:
        print(json.dumps({**line, "ok": False}), flush=True)
        print(f"{files[0]}: no /{args.laser}/colored messages (record with --log-colored)",
              file=sys.stderr)  # fmt: skip
        return
    command: list[str] | None = None
    if args.offline is None:
        with tempfile.TemporaryDirectory() as d:
            options = ["--no-balance"] if args.no_balance else []
            command = colorize(files, args.calib, Path(d) / "offline.ply", *options)
            offline = read_ply(Path(d) / "offline.ply")
    else:
        offline = read_ply(args.offline)
    print(json.dumps({**line, **agreement(live, offline, geometry), "offline_command": command,
                      "target": TARGET, "tolerance": TOLERANCE}), flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
