"""The recorder's bandwidth with large frames: one JSON line per result.

``record_bandwidth``: ``--cameras`` (4) cameras of a 5 MP sensor (2592x1944, a street
view enlarged with noise: JPEGs of about 1.3 MB, 10 of them cycled) and the scanner at
40 Hz, each from ``python -m acq.sim.prerendered`` in a process of its own, recorded 12 s
(5 s with ``--quick``) per step from 2 s after all connected, at 10, 15, 20, 25, 30, 35,
40, 50, 60, 75 Hz a camera until a step loses a record (checked as ``bench/recorder.py
--rate`` does, for every camera). Per step: MB/s written, the recorder's CPU (share of a
core, and per 100 MB/s), the simulators' CPU, the writer queue's high-water mark, the
load. A step passes with zero drops and its writer keeping up (the queue's high-water
mark under half its size, nothing left queued at the stop). ``record_bandwidth_max``:
the highest MB/s of a passing step; ``targets``: at least
150 MB/s. The files go to the system's temporary folder: its disk is part of what is
measured.

``acq record`` runs as a subprocess of its own and the simulated devices in other
processes, as in ``bench/recorder.py`` (whose log checks this reuses); every line
carries ``os.getloadavg()``: the machine has 2 cores and may be busy with other work.

Run as a script: ``python bench/recorder_bandwidth.py [--cameras N] [--fps HZ ...]
[--quick] [--keep]`` (about 4-5 minutes; ``--quick`` 2-3).
"""

from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path
from typing import Any

from processes import Procs, RecorderExited, workdir
from recorder import (
    Images,
    Prerendered,
    _expected_frames,
    _expected_scans,
    _line,
    _load,
    _short,
    camera_names,
    read_recorded,
    scanner_queue_drops,
    start_recorder,
)

from acq.record.recorder import QUEUE_SIZE

TARGET_MB_S = 150.0
SIZE = "2592x1944"  # a 5 MP sensor
STEPS = (10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0, 50.0, 60.0, 75.0)  # Hz a camera
FRAMES = 10  # distinct JPEGs each camera cycles


def _camera_stats(cameras: list[Prerendered]) -> list[dict[str, Any]]:
    return [c.stats() for c in cameras]


def _bandwidth_step(
    work: Path, fps: float, seconds: float, cameras: int, size: str, frames: int
) -> dict[str, Any]:
    """One step: ``cameras`` pre-rendered cameras of ``size`` at ``fps`` and the
    scanner at its nominal rate, each in a process of its own, recorded ``seconds``."""
    procs = Procs()
    err = (work / "sim.log").open("w")
    names = camera_names(cameras)
    try:
        scanner = Prerendered(procs, err, "scanner", "--model", "utm-30lx")
        sims = [
            Prerendered(procs, err, "camera", "--fps", str(fps), "--size", size,
                        "--frames", str(frames), "--seed", str(k))
            for k in range(cameras)
        ]  # fmt: skip
        # no calibration: the simulated rig's is of 780x582 cameras
        run = start_recorder(procs, work, scanner.url, [c.url for c in sims], fps, False)
        run.wait_for("laser connected", *(f"{n} connected" for n in names))
        warmup = time.monotonic() - run.t_start + 2.0
        run.sleep_until(warmup)
        t0, c0, _ = run.sample()
        b0 = run.bytes_on_disk()
        s0 = scanner.stats()["cpu_s"], sum(c["cpu_s"] for c in _camera_stats(sims))
        run.sleep_until(warmup + seconds)
        t1, c1, _ = run.sample()
        b1 = run.bytes_on_disk()
        load = _load()
        run.stop()
        s_stats, c_stats = scanner.stats(), _camera_stats(sims)
        rec = read_recorded(run.files())
        exp_scans = _expected_scans(s_stats["ticks"], rec.scan_ticks)
        frames_ok, per_camera = True, {}
        for name, stats in zip(names, c_stats, strict=True):
            got = len(rec.images.get(name, Images()).times)
            expected = _expected_frames(stats["frames"], rec, name)
            frames_ok = frames_ok and got == expected > 0
            per_camera[name] = f"{got}/{expected}"
        qdrops = scanner_queue_drops(rec)
        span = (t1 - t0) or 1.0
        mb_s = (b1 - b0) / span / 1e6
        cpu = (c1 - c0) / span
        ok = (
            qdrops == 0
            and len(rec.scan_ticks) == exp_scans > 0
            and frames_ok
            and not any(rec.info.disconnects.values())
        )
        # sustained, not only survived: the writer's queue stayed under half full and
        # nothing was left in it at the stop (a growing queue loses records later)
        kept_up = rec.max_writer_queue < QUEUE_SIZE // 2 and not any(
            "queued records not written" in w for w in run.warnings()
        )
        return {
            "cameras": cameras,
            "size": size,
            "fps": fps,
            "seconds": round(seconds, 1),
            "mb_per_s": round(mb_s, 1),
            "recorder_cpu_share": round(cpu, 3),
            "cpu_share_per_100_mb_s": round(cpu / mb_s * 100, 3) if mb_s > 0 else None,
            "scans": f"{len(rec.scan_ticks)}/{exp_scans}",
            "frames": per_camera,
            "scanner_queue_drops": qdrops,
            "drops": rec.info.drops,
            "disconnects": rec.info.disconnects,
            "max_writer_queue": rec.max_writer_queue,
            "sim_cpu_share": {
                "scanner": round((s_stats["cpu_s"] - s0[0]) / span, 3),
                "cameras": round((sum(c["cpu_s"] for c in c_stats) - s0[1]) / span, 3),
            },
            "sim_camera_late": sum(c["late"] for c in c_stats),
            "warnings": _short(run.warnings(), 3),
            "zero_drops": ok,
            "writer_kept_up": kept_up,
            "load_during": load,
        }
    except RecorderExited as e:
        return {"cameras": cameras, "fps": fps, "recorder_exit": e.code, "error": e.summary,
                "zero_drops": False}  # fmt: skip
    finally:
        procs.close()
        err.close()
        shutil.rmtree(work / "logs", ignore_errors=True)


def part_bandwidth(
    work: Path, seconds: float, cameras: int, size: str, steps: tuple[float, ...], frames: int
) -> None:
    """The frame rate stepped up until a step loses a record; ``record_bandwidth_max``
    is the highest MB/s written with zero drops."""
    best: dict[str, Any] | None = None
    failing = None
    for fps in steps:
        result = _bandwidth_step(work, fps, seconds, cameras, size, frames)
        _line("record_bandwidth", **result)
        if not (result["zero_drops"] and result.get("writer_kept_up")):
            failing = fps
            break
        if best is None or result["mb_per_s"] > best["mb_per_s"]:
            best = result
    mb_s = best["mb_per_s"] if best else 0.0
    _line(
        "record_bandwidth_max",
        mb_per_s=mb_s,
        at_fps=best["fps"] if best else None,
        recorder_cpu_share=best["recorder_cpu_share"] if best else None,
        cpu_share_per_100_mb_s=best["cpu_share_per_100_mb_s"] if best else None,
        first_failing_fps=failing,
        cameras=cameras,
        size=size,
    )
    _line("targets", record_bandwidth_mb_per_s=TARGET_MB_S, measured=mb_s,
          ok=mb_s >= TARGET_MB_S)  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--cameras", type=int, default=4, metavar="N",
        help="cameras serving 5 MP frames (default 4)",
    )  # fmt: skip
    parser.add_argument(
        "--fps", type=float, nargs="+", metavar="HZ",
        help="the frame rates to step through (default 10 15 20 25 30 35 40 50 60 75)",
    )  # fmt: skip
    parser.add_argument("--quick", action="store_true", help="5 s a step, not 12 s")
    parser.add_argument("--keep", action="store_true", help="keep the work folder")
    args = parser.parse_args()
    if args.cameras < 1:
        parser.error("--cameras: at least 1")
    if args.fps is not None and min(args.fps) <= 0:
        parser.error("--fps: every rate must be > 0 Hz")
    steps = tuple(args.fps or STEPS)
    with workdir("acq-bench-bandwidth-", args.keep) as work:
        part_bandwidth(work, 5.0 if args.quick else 12.0, args.cameras, SIZE, steps, FRAMES)


if __name__ == "__main__":
    main()
