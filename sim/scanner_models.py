"""The simulated scanner models: geometry, rates and identity, as the real devices report.

Hokuyo geometry is in SCIP's own terms (steps: AMIN..AMAX, front step AFRT, ARES steps
per turn, SCAN rpm), SICK's in its own (start angle and step in degrees with 90 degrees
straight ahead, scan frequency). ``geometry()`` converts both to the REP-103 laser frame
that ``acq`` uses, so tests can compare a driver's result with the truth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["MODELS", "ScannerModel", "model"]


@dataclass(frozen=True)
class ScannerModel:
    name: str
    vendor: str  # "hokuyo" | "sick"
    protocol: str  # "scip2.0" | "scip2.2" | "cola"
    product: str  # the device's own product string (SCIP PROD / CoLa DeviceIdent)
    firmware: str
    serial: str
    range_min: float  # m
    range_max: float  # m
    scan_hz: float
    intensity: bool  # the device can send intensities (SCIP ME / CoLa RSSI1)
    multi_echo: bool = False  # SCIP HD/ND/HE/NE
    # SCIP (steps)
    amin: int = 0
    amax: int = 0
    afrt: int = 0
    ares: int = 0
    # SICK (degrees, 90 straight ahead)
    start_deg: float = 0.0
    step_deg: float = 0.0
    n_points: int = 0
    dist_scale: float = 1.0  # SICK DIST1 scale factor (units of mm)
    rssi_bits: int = 16  # SICK: RSSI channel width the device sends by default (8 | 16)
    echoes: int = 1  # SICK: echoes per beam the device can output (DIST1..DISTn)
    eval_fields: int = 0  # SICK: evaluation fields readable as fieldNNN (0 = none)
    # SICK: (scan frequency 1/100 Hz, angular resolution 1/10000 degree) pairs that
    # mLMPsetscancfg accepts; empty = only the model's own
    scan_configs: tuple[tuple[int, int], ...] = ()
    ethernet: bool = False  # reachable over TCP (all SICK; UST and UTM-EW Hokuyos)
    serial_port: bool = False  # reachable over a (USB) serial port
    clock_bits: int = 24  # device tick counter width
    clock_hz: float = 1000.0  # device tick rate

    @property
    def steps(self) -> int:
        """Points per full scan."""
        return self.amax - self.amin + 1 if self.vendor == "hokuyo" else self.n_points

    @property
    def scan_period(self) -> float:
        return 1.0 / self.scan_hz

    @property
    def rpm(self) -> int:
        return round(self.scan_hz * 60)

    def angle_min(self) -> float:
        """REP-103 angle of the first point, rad."""
        if self.vendor == "hokuyo":
            return (self.amin - self.afrt) * 2 * math.pi / self.ares
        return math.radians(self.start_deg - 90.0)

    def angle_increment(self) -> float:
        """rad between points."""
        if self.vendor == "hokuyo":
            return 2 * math.pi / self.ares
        return math.radians(self.step_deg)

    def time_increment(self) -> float:
        """s between points: the mirror turns once a period over a full circle."""
        return self.scan_period * self.angle_increment() / (2 * math.pi)


MODELS: dict[str, ScannerModel] = {
    m.name: m
    for m in [
        ScannerModel(
            name="urg-04lx",
            vendor="hokuyo",
            protocol="scip2.0",
            product="SOKUIKI Sensor URG-04LX",
            firmware="3.4.03(17/Dec./2012)",
            serial="H1234567",
            range_min=0.02,
            range_max=5.6,
            scan_hz=10.0,
            intensity=False,
            amin=44,
            amax=725,
            afrt=384,
            ares=1024,
            serial_port=True,
        ),
        ScannerModel(
            name="utm-30lx",
            vendor="hokuyo",
            protocol="scip2.0",
            product="SOKUIKI Sensor TOP-URG UTM-30LX",
            firmware="1.1.20(19/Jan./2012)",
            serial="H0904856",
            range_min=0.023,
            range_max=60.0,
            scan_hz=40.0,
            intensity=True,
            multi_echo=True,
            amin=0,
            amax=1080,
            afrt=540,
            ares=1440,
            serial_port=True,
            ethernet=True,
        ),
        ScannerModel(
            name="ust-10lx",
            vendor="hokuyo",
            protocol="scip2.2",
            product="UST-10LX",
            firmware="1.2.6",
            serial="H1612345",
            range_min=0.02,
            range_max=30.0,
            scan_hz=40.0,
            intensity=True,
            amin=0,
            amax=1080,
            afrt=540,
            ares=1440,
            ethernet=True,
        ),
        ScannerModel(
            name="lms111",
            vendor="sick",
            protocol="cola",
            product="LMS1xx",
            firmware="V1.80",
            serial="12345678",
            range_min=0.5,
            range_max=20.0,
            scan_hz=50.0,
            intensity=False,
            start_deg=-45.0,
            step_deg=0.5,
            n_points=541,
            eval_fields=30,
            # LMS1xx telegram listing, mLMPsetscancfg: 25 Hz at 0.25 deg or 50 Hz at 0.5 deg
            scan_configs=((2500, 2500), (5000, 5000)),
            ethernet=True,
            clock_bits=32,
            clock_hz=1e6,
        ),
        ScannerModel(
            name="lms511",
            vendor="sick",
            protocol="cola",
            product="LMS5xx",
            firmware="V2.10",
            serial="14070001",
            range_min=0.7,
            range_max=80.0,
            scan_hz=25.0,
            intensity=True,
            start_deg=-5.0,
            step_deg=0.1667,  # as the device reports it: 1/10000 degree units
            n_points=1141,
            rssi_bits=8,  # the LMS5xx sends 8-bit RSSI unless told otherwise (LMDscandatacfg)
            echoes=5,
            eval_fields=30,
            # LMS500 operating instructions 8013796, 10.2.8: 25..100 Hz, 0.1667..1 degree;
            # the finer resolutions only at the lower frequencies (LMS5xx product data)
            scan_configs=(
                *((2500, r) for r in (1667, 2500, 3333, 5000, 6667, 10000)),
                *((3500, r) for r in (2500, 3333, 5000, 6667, 10000)),
                *((5000, r) for r in (3333, 5000, 6667, 10000)),
                *((7500, r) for r in (5000, 10000)),
                *((10000, r) for r in (6667, 10000)),
            ),
            ethernet=True,
            clock_bits=32,
            clock_hz=1e6,
        ),
        ScannerModel(
            name="tim781",
            vendor="sick",
            protocol="cola",
            product="TiM7xx",
            firmware="V2.50",
            serial="19400012",
            range_min=0.05,
            range_max=25.0,
            scan_hz=15.0,
            intensity=True,
            start_deg=-45.0,
            step_deg=0.3333,
            n_points=811,
            eval_fields=48,  # 16 field sets of 3 fields
            ethernet=True,
            clock_bits=32,
            clock_hz=1e6,
        ),
    ]
}


def model(name: str) -> ScannerModel:
    try:
        return MODELS[name]
    except KeyError:
        raise ValueError(
            f"unknown scanner model {name!r}; expected one of {', '.join(MODELS)}"
        ) from None
