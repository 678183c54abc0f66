"""Where simulated scanners get their ranges: the synthetic street, seen by the rig.

A scanner model's geometry (REP-103 angles, point timing, range limits) replaces the
rig's default UTM-30LX, so every model scans the same street from the same mount.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from acq.sim import sensors
from acq.sim.scanner_models import ScannerModel
from acq.sim.world import Rig, Street, Trajectory, default_rig

__all__ = ["StreetSource"]


class StreetSource:
    """Ranges (m) and intensities of one scan starting at true time ``t0`` (s).

    ``t0`` is host monotonic time; the drive starts at ``t_origin`` (by default when
    the source is made, i.e. when the device powers up) and loops over the street,
    so a device that runs for hours keeps scanning buildings.
    ``ranges``: +inf no echo (beyond range or sky), -inf too close, as REP-117.
    ``intensities``: a plausible return strength from range and surface colour.
    """

    def __init__(
        self,
        model: ScannerModel,
        street: Street | None = None,
        trajectory: Trajectory | None = None,
        rig: Rig | None = None,
        seed: int = 0,
        t_origin: float | None = None,
    ) -> None:
        self.model = model
        self.street = street if street is not None else Street.generate(seed=seed, length_m=1000.0)
        self.t_origin = time.monotonic() if t_origin is None else t_origin
        self.trajectory = trajectory if trajectory is not None else Trajectory()
        base = rig if rig is not None else default_rig()
        self.rig = replace(
            base,
            angle_min=model.angle_min(),
            angle_increment=model.angle_increment(),
            n_steps=model.steps,
            scan_period=model.scan_period,
            time_increment=model.time_increment(),
            max_range=model.range_max,
            min_range=model.range_min,
        )
        self.rng = np.random.default_rng(seed)
        # Power-up: compile or load the ray caster now, not in the middle of a stream.
        sensors.render_scan(self.street, self.trajectory, self.rig, 0.0, np.random.default_rng())

    def scan(self, t0: float) -> tuple[np.ndarray, np.ndarray]:
        """(ranges (N,) float64 m, intensities (N,) float64) of the scan starting at t0."""
        loop = max(self.street.length_m, 1.0) / self.trajectory.speed
        t_drive = (t0 - self.t_origin) % loop
        truth = sensors.render_scan(self.street, self.trajectory, self.rig, t_drive, self.rng)
        ranges = truth.ranges.astype(np.float64)
        return ranges, sensors.return_strength(ranges, truth.colours)
