"""SICK's own driver, sick_scan_xd 3.9.0, against the simulated LMS111 / LMS511 / TiM781
and against `acq replay` of a log recorded from them.

Each model's launch file is used with no overrides beyond host and port. The driver is
run once per model and device (the simulators side by side, then the replays side by
side, to keep the wall time short); every run is checked for what the driver delivered
through its Python API: enough point clouds, at the device's rate, with the device's
point count and first/last angles, ranges and (as configured) intensities. One
simulator powers up in CoLa-A, which the driver (set to CoLa-B) switches over.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import pytest

from acq.record import config as configfile
from acq.record.recorder import Recorder
from acq.sim.cola_device import ColaDevice
from acq.sim.devices import make_scanner
from acq.sim.replay import Replay
from acq.sim.transport import TcpDeviceServer
from tests import sick_client
from tests.sick_client import Run, run_sick_scan

# drives simulated devices and a vendor client in real time: run alone (`make test`)
pytestmark = [
    pytest.mark.realtime,
    pytest.mark.skipif(
        not sick_client.available(),
        reason=f"sick_scan_xd is absent from {sick_client.VENDOR} (CI has it)",
    ),
]


@dataclass(frozen=True)
class Case:
    model: str
    launch: str
    hz: float
    n_points: int
    first_deg: float  # SICK angle of the first point (90 = straight ahead)
    step_deg: float  # as the device reports it (1/10000 degree)
    rssi_max: float  # 0: no intensities asked for; 255: 8-bit; 65535: 16-bit


CASES = {
    c.model: c
    for c in [
        Case("lms111", "sick_lms_1xx.launch", 50.0, 541, -45.0, 0.5, 0.0),
        Case("lms511", "sick_lms_5xx.launch", 25.0, 1141, -5.0, 0.1667, 255.0),
        Case("tim781", "sick_tim_7xx.launch", 15.0, 811, -45.0, 0.3333, 65535.0),
    ]
}
COLA_A = "tim781"  # this one also runs powered up in CoLa-A
CLOUDS_S = 1.0  # s of point clouds to collect from each run
TIMEOUT_S = 20.0  # the CoLa-A run waits 5 s for a CoLa-B answer first, as on a real device


def _port(url: str) -> int:
    return int(url.rsplit(":", 1)[1])


def _count(case: Case) -> int:
    return math.ceil(CLOUDS_S * case.hz)


@dataclass
class Runs:
    """What sick_scan_xd delivered from each simulator and each replay, the simulated
    devices (their state after the driver configured them) and the replay's complaints."""

    simulated: dict[str, Run]
    devices: dict[str, ColaDevice]
    replayed: dict[str, Run]
    replay_errors: list[str]


def _serve(name: str, protocol: str = "cola-b") -> tuple[ColaDevice, TcpDeviceServer]:
    _model, device = make_scanner(name, protocol=protocol)
    assert isinstance(device, ColaDevice)
    return device, TcpDeviceServer(device).start()


def _record(logs: Path) -> list[Path]:
    """A short log of the three simulated models, recorded by `acq record`'s recorder."""
    servers = {name: _serve(name)[1] for name in CASES}
    try:
        scanners = [
            {"name": name, "driver": "sick", "url": f"tcp://{s.host}:{s.port}"}
            for name, s in servers.items()
        ]
        data = {"version": 1, "scanners": scanners, "output": {"dir": str(logs)}}
        assert Recorder(configfile.parse(data), duration_s=CLOUDS_S + 1.0).run() == 0
    finally:
        for server in servers.values():
            server.close()
    return sorted(logs.glob("*.mcap"))


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Runs]:
    """All runs side by side: the driver against each simulator (and the CoLa-A one)
    while the log is recorded from other simulated devices, then against its replay."""
    devices: dict[str, ColaDevice] = {}
    servers = []
    jobs = [*((m, m, "cola-b") for m in CASES), (f"{COLA_A}-cola-a", COLA_A, "cola-a")]
    with ThreadPoolExecutor(len(jobs) + len(CASES)) as pool:
        try:
            futures = {}
            for key, name, protocol in jobs:
                device, server = _serve(name, protocol)
                servers.append(server)
                devices[key] = device
                case = CASES[name]
                futures[key] = pool.submit(
                    run_sick_scan, case.launch, server.port, _count(case), TIMEOUT_S
                )
            files = _record(tmp_path_factory.mktemp("sick-log") / "logs")
            with Replay(files) as replay:
                replay_futures = {
                    name: pool.submit(
                        run_sick_scan, c.launch, _port(replay.urls[name]), _count(c), TIMEOUT_S
                    )
                    for name, c in CASES.items()
                }
                replayed = {name: f.result() for name, f in replay_futures.items()}
                errors = list(replay.errors)
            simulated = {key: f.result() for key, f in futures.items()}
        finally:
            for server in servers:
                server.close()
    yield Runs(simulated, devices, replayed, errors)


def _check(run: Run, case: Case, what: str) -> None:
    need = _count(case)
    assert len(run.clouds) >= need, (
        f"{what}: sick_scan_xd delivered {len(run.clouds)} of {need} clouds;"
        f" its log ends:\n{run.tail()}"
    )
    # the rate sick_scan_xd sees over its short run: a host that holds a sender up and
    # then lets a few telegrams through together moves it by 10-15 % (56 Hz of 50 seen)
    assert run.rate() == pytest.approx(case.hz, rel=0.2), f"{what}: {run.rate():.2f} Hz"
    first = math.radians(case.first_deg - 90.0)
    step = round(case.step_deg * 10000) / 10000
    last = math.radians(case.first_deg + (case.n_points - 1) * step - 90.0)
    for cloud in run.clouds:
        assert cloud.width == case.n_points, what
        assert cloud.azimuth_first == pytest.approx(first, abs=1e-4), what
        assert cloud.azimuth_last == pytest.approx(last, abs=1e-4), what
        assert cloud.valid > 0.5 * case.n_points, f"{what}: {cloud.valid} ranges"
        assert 0.0 <= cloud.intensity_max <= case.rssi_max, what
    if case.rssi_max:
        assert max(c.intensity_max for c in run.clouds) > 0, f"{what}: no intensities"


@pytest.mark.parametrize("name", list(CASES))
def test_sick_scan_xd_reads_the_simulator(runs: Runs, name: str) -> None:
    case = CASES[name]
    _check(runs.simulated[name], case, f"{name} simulator")
    shape = runs.devices[name].shape()  # what the driver configured, as the device holds it
    assert (shape.n_points, shape.start, shape.frequency) == (
        case.n_points,
        round(case.first_deg * 10000),
        round(case.hz * 100),
    )
    assert shape.rssi_bits == {0.0: 0, 255.0: 8, 65535.0: 16}[case.rssi_max]


def test_sick_scan_xd_switches_a_cola_a_simulator(runs: Runs) -> None:
    key = f"{COLA_A}-cola-a"
    _check(runs.simulated[key], CASES[COLA_A], f"{COLA_A} simulator powered up in CoLa-A")
    assert runs.devices[key].protocol == "cola-b"  # the driver wrote EIHstCola 1


@pytest.mark.parametrize("name", list(CASES))
def test_sick_scan_xd_reads_a_replay(runs: Runs, name: str) -> None:
    _check(runs.replayed[name], CASES[name], f"{name} replay")
    assert not [e for e in runs.replay_errors if e.startswith(name)]
