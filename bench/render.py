"""Single-core speed of the simulator: fisheye frames and laser scans per second.

Prints one JSON line per result. Run as a script: ``python bench/render.py``.
"""

from __future__ import annotations

import os

os.environ["NUMBA_NUM_THREADS"] = "1"  # before numba is imported: one core

import json
import statistics
import time
from collections.abc import Callable

import numpy as np

from acq.sim.sensors import pixel_rays, render_frame, render_scan
from acq.sim.world import Street, Trajectory, default_rig

REPEATS = 9
CALLS = 10  # per repeat


def _median_rate(fn: Callable[[int], object]) -> float:
    """Median calls per second over REPEATS repeats of CALLS calls, after a warm-up."""
    fn(0)
    rates = []
    for r in range(REPEATS):
        start = time.perf_counter()
        for i in range(CALLS):
            fn(r * CALLS + i)
        rates.append(CALLS / (time.perf_counter() - start))
    return statistics.median(rates)


def main() -> None:
    street = Street.generate(seed=0, length_m=300.0)
    trajectory = Trajectory()
    rig = default_rig()
    lens = rig.lens
    fps = _median_rate(lambda i: render_frame(street, trajectory, rig, 5.0 + i / rig.fps))
    rays = pixel_rays(lens)[0].shape[0]
    print(
        json.dumps(
            {
                "bench": "render_fisheye",
                "width": lens.width,
                "height": lens.height,
                "rays_per_frame": rays,
                "fps_median": round(fps, 2),
                "mrays_per_s": round(fps * rays / 1e6, 2),
                "repeats": REPEATS,
                "calls_per_repeat": CALLS,
                "threads": 1,
            }
        )
    )
    rng = np.random.default_rng(0)
    sps = _median_rate(lambda i: render_scan(street, trajectory, rig, 5.0 + i * 0.025, rng))
    print(
        json.dumps(
            {
                "bench": "render_scan",
                "steps": rig.n_steps,
                "scans_per_s_median": round(sps, 1),
                "repeats": REPEATS,
                "calls_per_repeat": CALLS,
                "threads": 1,
            }
        )
    )


if __name__ == "__main__":
    main()
