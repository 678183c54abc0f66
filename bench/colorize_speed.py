"""`acq colorize` against the decode limit, both measured in the same run (issue 32).

Data: the 60 s two-camera drive (``acq.sim.drive_log.write_drive_log`` on
``acq.sim.world.default_rig(cameras=2)``, the rig ``acq demo`` records: a left and a
right 185-degree fisheye of 780x582 px at 25 Hz, a UTM-30LX at 40 Hz, CAN odometry) and
its true calibration, written once into the work folder and kept there.

Alternating, ``--repeat`` (3) times each, every run a new process measured from outside
(wall time from its start to its exit, peak memory from ``os.wait4``'s rusage maxrss
and CPU time (user + system) from the same rusage, the whole process):

(a) ``colorize``: ``acq colorize LOG --calib calib.yaml -o OUT.ply --force``, the
    defaults a user gets (the preview included);
(b) ``decode_limit``: the decode limit, :func:`decode_limit` in a new process: read every
    frame of the log and decode it once on every core (``acq.camera.jpeg``, simplejpeg),
    nothing else.

One JSON line per result: ``drive``; ``run`` (each process, with ``os.getloadavg()``);
``speed`` (both medians side by side and their ratio, with the CPU seconds of each:
on ``cores`` cores a process takes at least its CPU time / cores, so
``ratio_floor_from_cpu`` is the ratio no overlapping of work can beat); ``targets`` (ratio <= 1.25,
colorize's peak <= 600 MB). The machine may be busy with other work: the load is in
every line, and the alternation gives both the same share of it.

Run as a script: ``python bench/colorize_speed.py [--seconds S] [--repeat N] [--work DIR]``
(``--decode-limit LOG...``: one decode-limit run, as (b) starts it).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

RATIO_TARGET = 1.25
PEAK_TARGET_MB = 600.0


def _line(bench: str, **fields: Any) -> None:
    print(json.dumps({"bench": bench, **fields}), flush=True)


def _load() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


def decode_limit(files: list[Path]) -> dict[str, Any]:
    """Read every frame of the log ``files`` and decode it once on every core (threads
    of ``acq.camera.jpeg.decode_jpeg_transient``, simplejpeg releasing the GIL), nothing
    else: the figure colouring cannot beat with a whole-frame decoder. Seconds of each
    part; run it in a new process to count its start too."""
    from concurrent.futures import ThreadPoolExecutor

    from acq.camera.jpeg import decode_jpeg_transient
    from acq.log.reader import LogReader

    t0 = time.perf_counter()
    jpegs: list[bytes] = []
    for path in files:
        reader = LogReader(path, progress=False)
        for schema, channel, message in reader.messages():
            if channel.topic.endswith("/image/compressed"):
                msg = reader.decode(schema, channel, message)
                if msg is not None:
                    jpegs.append(bytes(msg.data))
    t_read = time.perf_counter()
    cores = os.cpu_count() or 1
    with ThreadPoolExecutor(max_workers=cores) as pool:
        decoded = sum(
            image is not None for image in pool.map(decode_jpeg_transient, jpegs, chunksize=16)
        )
    t_end = time.perf_counter()
    return {
        "frames": len(jpegs),
        "decoded": decoded,
        "cores": cores,
        "read_s": round(t_read - t0, 3),
        "decode_s": round(t_end - t_read, 3),
        "ms_per_frame_core": round((t_end - t_read) * cores / max(len(jpegs), 1) * 1e3, 3),
    }


def drive(work: Path, seconds: float) -> tuple[list[Path], Path, float]:
    """The two-camera drive of ``seconds`` and its true calibration in ``work``, written
    once (by a process of its own: a forked child's maxrss starts from its parent's, so
    this one stays small) and then kept: (log files, calib.yaml, its length in s)."""
    folder = work / f"drive_{seconds:g}s"
    done = folder / "done.json"
    if not done.exists():
        t0 = time.perf_counter()
        subprocess.run([sys.executable, __file__, "--write-drive", str(folder), str(seconds)],
                       check=True)  # fmt: skip
        kept = json.loads(done.read_text())
        _line("drive", seconds=seconds, **kept, wall_s=round(time.perf_counter() - t0, 1),
              load=_load())  # fmt: skip
    kept = json.loads(done.read_text())
    return [Path(f) for f in kept["files"]], folder / "calib.yaml", float(kept["duration_s"])


def write_drive(folder: Path, seconds: float) -> None:
    """:func:`drive`'s drive written into ``folder``, ``done.json`` last."""
    from acq.camera import calibfile
    from acq.sim.drive_log import write_drive_log
    from acq.sim.world import default_rig

    truth = write_drive_log(folder / "log", seconds, rig=default_rig(cameras=2))
    calibfile.save(truth.calibration, folder / "calib.yaml")
    kept = {
        "files": [str(f) for f in truth.files],
        "duration_s": float(truth.scan_t0_s[-1] - truth.scan_t0_s[0]),
        "cameras": list(truth.camera_names),
        "bytes": sum(f.stat().st_size for f in truth.files),
    }
    (folder / "done.json").write_text(json.dumps(kept))


def measured(cmd: list[str]) -> tuple[float, float, float, str]:
    """``cmd`` run as a new process: (wall s, peak memory MB and CPU s (user + system)
    of the whole process from its ``os.wait4`` rusage, its stdout); RuntimeError with its
    stderr's end when it fails."""
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=out, stderr=err, text=True)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)  # reaped here, not by Popen
        out.seek(0)
        err.seek(0)
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd[:4])} failed ({proc.returncode}): "
                               f"{err.read()[-2000:]}")  # fmt: skip
        return wall, usage.ru_maxrss / 1024, usage.ru_utime + usage.ru_stime, out.read()


def compare(
    files: list[Path], calib: Path, out: Path, duration_s: float, repeat: int
) -> dict[str, Any]:
    """(a) and (b) of the module docstring, alternating, ``repeat`` times each: a
    ``run`` line per process; the medians side by side and their ratio."""
    colorize = [sys.executable, "-m", "acq.cli", "colorize", *map(str, files), "--calib",
                str(calib), "-o", str(out), "--force"]  # fmt: skip
    limit = [sys.executable, __file__, "--decode-limit", *map(str, files)]
    runs: dict[str, list[tuple[float, float, float]]] = {"colorize": [], "decode_limit": []}
    parts: list[dict[str, Any]] = []
    for k in range(repeat):
        for kind, cmd in (("colorize", colorize), ("decode_limit", limit))[
            :: 1 if k % 2 == 0 else -1
        ]:
            load = _load()
            wall, peak, cpu, stdout = measured(cmd)
            runs[kind].append((wall, peak, cpu))
            extra = json.loads(stdout) if kind == "decode_limit" else {}
            if extra:
                parts.append(extra)
            _line("run", kind=kind, wall_s=round(wall, 3), peak_mb=round(peak, 1),
                  cpu_s=round(cpu, 3), load_before=load, load_after=_load(),
                  **extra)  # fmt: skip
    med = {
        kind: [statistics.median(column) for column in zip(*r, strict=True)]
        for kind, r in runs.items()
    }
    (c_wall, c_peak, c_cpu), (d_wall, d_peak, d_cpu) = med["colorize"], med["decode_limit"]
    cores = os.cpu_count() or 1
    return {
        "runs": repeat,
        "drive_s": round(duration_s, 2),
        "colorize_wall_s": round(c_wall, 3),
        "colorize_peak_mb": round(c_peak, 1),
        "decode_limit_wall_s": round(d_wall, 3),
        "decode_limit_peak_mb": round(d_peak, 1),
        "ratio": round(c_wall / d_wall, 3),
        "colorize_cpu_s": round(c_cpu, 3),
        "decode_limit_cpu_s": round(d_cpu, 3),
        "cores": cores,
        # colorize cannot take less than its CPU time over the cores
        "ratio_floor_from_cpu": round(c_cpu / cores / d_wall, 3),
        "colorize_real_time_multiple": round(duration_s / c_wall, 1),
        "decode_limit_real_time_multiple": round(duration_s / d_wall, 1),
        "decode_limit_frames": parts[0]["frames"] if parts else 0,
        "decode_limit_ms_per_frame_core": statistics.median(p["ms_per_frame_core"] for p in parts),
        "load": _load(),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="the drive's length (60)")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each, alternating (3)")
    ap.add_argument("--work", type=Path, help="keep the drive here (default: a temporary folder)")
    ap.add_argument("--decode-limit", nargs="+", type=Path, metavar="LOG",
                    help="only run the decode limit on LOG, one JSON line (run (b))")  # fmt: skip
    ap.add_argument("--write-drive", nargs=2, metavar=("DIR", "SECONDS"),
                    help="only write the drive into DIR (as the bench does first)")  # fmt: skip
    args = ap.parse_args()
    if args.write_drive:
        write_drive(Path(args.write_drive[0]), float(args.write_drive[1]))
        return
    if args.decode_limit:
        print(json.dumps(decode_limit(args.decode_limit)))
        return
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        files, calib, duration = drive(work, args.seconds)
        speed = compare(files, calib, work / "speed.ply", duration, args.repeat)
        _line("speed", **speed)
        _line("targets", ratio=speed["ratio"], ratio_ok=speed["ratio"] <= RATIO_TARGET,
              colorize_peak_mb=speed["colorize_peak_mb"],
              peak_ok=speed["colorize_peak_mb"] <= PEAK_TARGET_MB, load=_load())  # fmt: skip


if __name__ == "__main__":
    main()
