"""The Hokuyo clients real users run, against the simulated devices and a replay of a log
recorded from one: Hokuyo's urg_library samples over Ethernet and a pty, and hokuyolx
(Ethernet only: it opens a TCP socket). What they read is checked against what the
device sent. What a real model does not support fails as on the real one."""

from __future__ import annotations

import gc
import math
import re
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from acq.record import config as configfile
from acq.record.recorder import Recorder
from acq.sim.replay import Replay
from acq.sim.scanner_models import MODELS
from acq.sim.scip_device import ScipDevice
from acq.sim.transport import PtyDeviceServer, TcpDeviceServer
from tests.hokuyo_client import (
    ETHERNET,
    SAMPLE_PORT,
    run_sample,
    sample_port,
    samples,
    serial,
)

# the samples' port is fixed: these tests serve it one at a time
pytestmark = pytest.mark.realtime


@pytest.fixture(autouse=True)
def _one_test_at_a_time_on_the_sample_port() -> Iterator[None]:
    """Every test here serves or reads port 10940 (the samples' own): one at a time."""
    with sample_port():
        yield


hokuyolx = pytest.importorskip("hokuyolx")
DISTANCE = re.compile(r"^(-?\d+) \[mm\], (?:(\d+) \[1\], )?\((\d+) \[msec\]\)$")


def check_front_ranges(dev: ScipDevice, lines: list[str], intensity: bool) -> None:
    """Each ``get_distance[_intensity]`` line: the front step of a scan the device sent,
    one scan period after the one before."""
    front = dev.model.afrt - dev.model.amin
    sent = {s.timestamp: s for s in dev.sent}
    stamps = []
    for line in lines:
        m = DISTANCE.match(line)
        assert m, line
        scan = sent[int(m[3])]
        assert int(m[1]) == scan.ranges_mm[front]
        if intensity:
            assert scan.intensities is not None and int(m[2]) == scan.intensities[front]
        stamps.append(int(m[3]))
    period_ms = 1000 * dev.period
    assert np.allclose(np.diff(stamps), period_ms, atol=1.5), stamps


def check_xy(dev: ScipDevice, lines: list[str]) -> None:
    """``calculate_xy``: x, y of every valid step of the single scan sent, mm."""
    scan, m = dev.sent[-1], dev.model
    assert scan.command == "GD"
    xy = np.array([[int(v) for v in line.split(",")] for line in lines if line])
    steps = np.arange(scan.start, scan.end + 1)
    ok = (scan.ranges_mm >= dev.dmin) & (scan.ranges_mm <= dev.dmax)
    angle = (steps[ok] - m.afrt) * 2 * math.pi / m.ares
    want = np.stack([scan.ranges_mm[ok] * np.cos(angle), scan.ranges_mm[ok] * np.sin(angle)], 1)
    assert xy.shape == want.shape and np.abs(xy - want).max() <= 1.0


# (model, transport, the samples run). A streaming sample is killed after 3 scans; over a
# pty nothing tells the device its client is gone and it streams on, as a USB one would
# (the next urg_open would wait for silence): there it comes last.
CASES = [
    ("ust-10lx", "tcp", ["get_distance_intensity", "get_multiecho", "sensor_parameter",
                         "sync_time_stamp", "calculate_xy", "reboot_test"]),
    ("utm-30lx", "tcp", ["sensor_parameter", "get_distance", "get_multiecho_intensity",
                         "calculate_xy"]),
    ("utm-30lx", "pty", ["sensor_parameter", "sync_time_stamp", "reboot_test",
                         "get_multiecho"]),
    ("urg-04lx", "tcp", ["sensor_parameter", "calculate_xy", "get_distance"]),
    ("urg-04lx", "pty", ["sensor_parameter", "sync_time_stamp", "calculate_xy",
                         "reboot_test", "get_distance"]),
]  # fmt: skip


@pytest.mark.parametrize(("name", "transport", "programs"), CASES)
def test_urg_library_samples(name: str, transport: str, programs: list[str]) -> None:
    samples()
    model = MODELS[name]
    dev = ScipDevice(model)
    server = TcpDeviceServer(dev, port=SAMPLE_PORT) if transport == "tcp" else PtyDeviceServer(dev)
    with server:
        target = ETHERNET if transport == "tcp" else serial(server.url)
        for program in programs:
            if program in ("get_distance", "get_distance_intensity"):
                run = run_sample(program, target, lines=3)
                if program.endswith("intensity") and not model.intensity:
                    assert run.lines == ["urg_get_distance_intensity: invalid response."]
                else:
                    check_front_ranges(dev, run.lines, program.endswith("intensity"))
            elif program.startswith("get_multiecho"):
                run = run_sample(program, target, lines=3)
                if model.multi_echo:  # front step: 3 echoes (and intensities), time stamp
                    assert all(len(line.split(",")) == (7 if "intensity" in program else 4)
                               for line in run.lines), run.lines  # fmt: skip
                else:  # ND/NE: 0E, as on the real model
                    assert run.returncode == 1 and "invalid response" in run.lines[0]
            elif program == "sensor_parameter":
                run = run_sample(program, target)
                assert run.returncode == 0
                assert f"Sensor product type: {model.product}" in run.lines
                assert f"sensor data size: {model.amax + 1}" in run.lines
                assert f"scan interval: {round(1e6 / model.scan_hz)} [usec]" in run.lines
            elif program == "sync_time_stamp":  # PC and sensor time, then corrected
                run = run_sample(program, target)
                assert run.returncode == 0 and len(run.lines) == 8, run.lines
                offsets = [int(line.split(",")[1]) - int(line.split(",")[0])
                           for line in run.lines[3:]]  # fmt: skip
                # within a round trip of the TM exchange the sample corrects by: a few ms
                # idle, 43 seen on a busy host keeping the simulator's reply waiting; a
                # clock in another unit or on another base is off by far more
                assert max(map(abs, offsets)) <= 150, run.lines
            elif program == "calculate_xy":
                run = run_sample(program, target)
                assert run.returncode == 0
                check_xy(dev, run.lines)
            elif program == "reboot_test":  # RB twice: a UST reboots, SCIP 2.0 says 0E
                reboots = dev.clock.reboots
                assert run_sample(program, target).returncode == 0
                assert dev.clock.reboots == reboots + (model.protocol == "scip2.2")
            else:
                raise AssertionError(program)


def _sensor_state(laser: Any) -> dict[str, Any]:
    """hokuyolx's ``sensor_state()`` (II), asked again when it fails to split a line: it
    splits each on ':', which the UST's 4-character TIME can hold (':' encodes 10), as
    against a real UST. The device's timer started at 0 (the test's power-on), its first
    two characters stay '0' for 4 s; the last two change every 1 and 64 ms."""
    for _ in range(4):
        try:
            state: dict[str, Any] = laser.sensor_state()
            return state
        except ValueError:
            time.sleep(0.07)  # the next TIME of another third character
    state = laser.sensor_state()
    return state


def test_hokuyolx_drives_a_ust_10lx() -> None:
    dev = ScipDevice(MODELS["ust-10lx"])
    dev.clock.epoch = time.monotonic()  # powered on now: its timer starts at 0 (see above)
    with TcpDeviceServer(dev, port=SAMPLE_PORT):
        laser = hokuyolx.HokuyoLX(addr=("127.0.0.1", SAMPLE_PORT))  # %ST, TM, PP, BM
        try:
            assert laser.laser_state() == (3, "Single scan state")
            assert (laser.model, laser.amax, laser.aforw, laser.scan_freq) == ("UST-10LX", 1080,
                                                                               540, 40)  # fmt: skip
            assert laser.version()["PROT"] == "SCIP 2.2"
            assert _sensor_state(laser)["LASR"] == "ON"
            ts, dist = laser.get_dist()
            assert np.array_equal(dist, dev.sent[-1].ranges_mm)
            assert abs(time.time() * 1000 - ts) < 200  # stamp synchronised to host time
            ts, scan = laser.get_filtered_intens()
            sent = dev.sent[-1]
            ok = (sent.ranges_mm >= 20) & (sent.ranges_mm <= 30000)
            assert np.array_equal(scan[:, 1:], np.stack([sent.ranges_mm, sent.intensities], 1)[ok])
            got = list(laser.iter_intens(scans=3))
            assert [pending for _, _, pending in got] == [2, 1, 0]
            assert np.array_equal(got[-1][0][:, 0], dev.sent[-1].ranges_mm)
            stream = laser.iter_filtered_dist()  # endless, then QT
            assert next(stream)[0].shape[1] == 2
            assert laser.laser_state() == (4, "Multi scan state")
            laser.standby()
            assert laser.laser_state() == (0, "Standby state")
            laser.sleep()
            assert laser.laser_state() == (5, "Sleep state")
            assert laser.activate()[0] == 0
            laser.partial_reset()
            assert laser.laser_state() == (0, "Standby state")
            laser.reset()
            laser.reboot()
            assert dev.clock.reboots == 1
        finally:
            laser.close()


@pytest.mark.parametrize("name", ["urg-04lx", "utm-30lx"])
def test_hokuyolx_meets_the_scip20_models_as_real_ones(name: str) -> None:
    """hokuyolx's default constructor asks %ST, which SCIP 2.0 devices do not know: 0E.
    Without its time sync (and its time conversion, which needs it) it reads scans."""
    dev = ScipDevice(MODELS[name])
    with TcpDeviceServer(dev, port=SAMPLE_PORT):
        with pytest.raises(hokuyolx.exceptions.HokuyoStatusException) as e:
            hokuyolx.HokuyoLX(addr=("127.0.0.1", SAMPLE_PORT))
        assert e.value.code == "0E"
        del e  # its traceback holds that client's socket: the device serves one at a time
        gc.collect()
        laser = hokuyolx.HokuyoLX(addr=("127.0.0.1", SAMPLE_PORT), tsync=False, convert_time=False)
        try:
            ts, dist = laser.get_dist()
            assert ts == dev.sent[-1].timestamp and np.array_equal(dist, dev.sent[-1].ranges_mm)
            if dev.model.intensity:
                assert laser.get_intens()[1].shape == (dev.model.steps, 2)
            else:
                with pytest.raises(hokuyolx.exceptions.HokuyoStatusException) as e:
                    laser.get_intens()
                assert e.value.code == "0E"
        finally:
            laser.close()


@pytest.fixture(scope="module")
def ust_log(tmp_path_factory: pytest.TempPathFactory) -> Iterator[list[Path]]:
    """2 s of a simulated UST-10LX recorded by acq (ME: distances and intensities)."""
    tmp = tmp_path_factory.mktemp("ust")
    with TcpDeviceServer(ScipDevice(MODELS["ust-10lx"])) as server:
        scanner = {"name": "laser", "driver": "hokuyo", "url": server.url,
                   "options": {"intensity": True}}  # fmt: skip
        data = {"version": 1, "scanners": [scanner], "output": {"dir": str(tmp / "logs")}}
        assert Recorder(configfile.parse(data), duration_s=2.0).run() == 0
    yield sorted((tmp / "logs").glob("*.mcap"))


def test_a_replay_serves_hokuyolx(ust_log: list[Path]) -> None:
    with Replay(ust_log, scanner_listen=f"tcp://127.0.0.1:{SAMPLE_PORT}") as replay:
        laser = hokuyolx.HokuyoLX(addr=("127.0.0.1", SAMPLE_PORT))  # starts the replay
        try:
            assert laser.laser_state() == (3, "Single scan state")
            ts, dist = laser.get_dist()  # GD from the recorded ME stream
            assert dist.shape == (1081,) and abs(time.time() * 1000 - ts) < 200
            got = list(laser.iter_intens(scans=2))
            assert [pending for _, _, pending in got] == [1, 0]
        finally:
            laser.close()
        assert not replay.errors


def test_a_replay_serves_urg_library(ust_log: list[Path]) -> None:
    samples()
    with Replay(ust_log, scanner_listen=f"tcp://127.0.0.1:{SAMPLE_PORT}") as replay:
        run = run_sample("get_distance", ETHERNET, lines=3)  # MD: the distances of ME
        matches = [DISTANCE.match(line) for line in run.lines]
        stamps = [int(m[3]) for m in matches if m]
        assert len(stamps) == 3 and np.allclose(np.diff(stamps), 25, atol=1.5), run.lines
        run = run_sample("calculate_xy", ETHERNET)  # GD: a recorded scan
        assert run.returncode == 0 and len(run.lines) > 500
        assert not replay.errors
