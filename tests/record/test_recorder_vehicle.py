"""The recorder with the vehicle's sensors: the simulated UTM-30LX on TCP, the simulated
car on a python-can ``virtual`` bus (in this process, where the recorder runs) and the
simulated GNSS receiver on a pty, all driving one trajectory from one instant; the MCAP
holds /vehicle/odometry, /vehicle/can, /gnss/fix, /gnss/raw with their rates and true
values, and :func:`acq.log.vehicle_log.read_vehicle` reads them back. Nothing is mocked."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import yaml

from acq.log import info, read_metadata
from acq.log.summary import gaps
from acq.log.vehicle_log import read_vehicle
from acq.record import config as configfile
from acq.record.recorder import Recorder, RecorderError
from acq.sim import replay
from acq.sim.can_vehicle import DBC_PATH, WHEEL_SPEEDS_ID, YAW_RATE_ID, SentFrame, SimVehicle
from acq.sim.nmea_device import NmeaDevice, NmeaPtyServer
from acq.sim.scanner_models import MODELS
from acq.sim.scip_device import ScipDevice
from acq.sim.transport import TcpDeviceServer
from acq.sim.world import Trajectory
from tests.sim_rig import read_log

# drives simulated devices in real time: run alone (`make test`)
pytestmark = pytest.mark.realtime

CURVY = Trajectory(curve_amplitude=2.0, curve_wavelength=60.0)
SECONDS = 4.0
GNSS_LATENCY_S = 0.040  # the simulated receiver's constant delay (jitter on top)


@dataclass
class VehicleRig:
    scanner: TcpDeviceServer
    car: SimVehicle
    gnss: NmeaDevice
    gnss_server: NmeaPtyServer
    channel: str

    def config(self, tmp_path: Path, **can: object) -> configfile.Config:
        data = {
            "version": 1,
            "scanners": [{"name": "laser", "driver": "hokuyo", "url": self.scanner.url}],
            "can": {"interface": "virtual", "channel": self.channel, "dbc": str(DBC_PATH),
                    **can},
            # stamped from receipt: the receiver's UTC is 2.5 s off the host's wall clock
            "gnss": {"url": self.gnss_server.url, "baudrate": 115200, "time": "receipt",
                     "latency_s": GNSS_LATENCY_S},
            "output": {"dir": str(tmp_path / "logs")},
        }  # fmt: skip
        path = tmp_path / "rig.yaml"
        path.write_text(yaml.safe_dump(data))
        return configfile.load(path)

    def close(self) -> None:
        self.car.close()
        self.gnss_server.close()
        self.scanner.close()


@pytest.fixture(scope="module")
def rig() -> Iterator[VehicleRig]:
    t0 = time.monotonic()
    channel = f"acq-recorder-vehicle-{time.monotonic_ns()}"
    gnss = NmeaDevice(CURVY, t_origin=t0, utc_offset_s=time.time() - time.monotonic() - 2.5)
    r = VehicleRig(
        scanner=TcpDeviceServer(ScipDevice(MODELS["utm-30lx"])).start(),
        car=SimVehicle("virtual", channel, trajectory=CURVY, t_origin=t0).start(),
        gnss=gnss,
        gnss_server=NmeaPtyServer(gnss).start(),
        channel=channel,
    )
    try:
        yield r
    finally:
        r.close()


def stamp(msg: object) -> int:
    ts = msg.timestamp  # type: ignore[attr-defined]
    return int(ts.seconds) * 1_000_000_000 + int(ts.nanos)


def test_record_the_vehicle_sensors(rig: VehicleRig, tmp_path: Path) -> None:
    cfg = rig.config(tmp_path)

    def faults() -> None:  # a frame of a wrong length, a sentence with a wrong checksum
        rig.car.send_raw(WHEEL_SPEEDS_ID, b"\x01\x02\x03")
        rig.gnss_server.corrupt_checksum()

    timer = threading.Timer(SECONDS / 2, faults)
    timer.start()
    try:
        assert Recorder(cfg, duration_s=SECONDS).run() == 0
    finally:
        timer.cancel()
    (path,) = sorted((tmp_path / "logs").glob("*.mcap"))
    log = read_log(path)
    odo, can, fixes, raw = (log[t] for t in ("/vehicle/odometry", "/vehicle/can", "/gnss/fix",
                                             "/gnss/raw"))  # fmt: skip

    def rate(records: list[tuple[int, int, object]]) -> float:
        return (len(records) - 1) / ((records[-1][0] - records[0][0]) * 1e-9)

    # rates: odometry 50 + 50 per s, all frames 200 per s, fixes 10, sentences 30 per s
    assert rate(odo) == pytest.approx(100, rel=0.05)
    assert rate(can) == pytest.approx(200, rel=0.05)
    assert rate(fixes) == pytest.approx(10, rel=0.1)
    assert rate(raw) == pytest.approx(30, rel=0.1)
    assert len(log["/acq/timing/gnss"]) == len(fixes) and len(log["/laser/scan"]) > 100
    # odometry: the true motion, within the DBC's steps, stamped when sent
    truth: dict[tuple[int, bytes], list[SentFrame]] = {}
    for s in rig.car.truth:
        truth.setdefault((s.arbitration_id, s.data), []).append(s)
    frames = {(stamp(m), m.arbitration_id): m for _, _, m in can}  # type: ignore[attr-defined]
    speed_err, yaw_err, stamp_err = [], [], []
    for log_time, pub, m in odo:
        assert stamp(m) == pub and m.recv_ns == log_time  # type: ignore[attr-defined]
        frame = frames[(pub, m.arbitration_id)]  # type: ignore[attr-defined]  # its raw frame
        same = truth[(frame.arbitration_id, frame.data)]  # type: ignore[attr-defined]
        sent = min(same, key=lambda s: abs(s.t_sent * 1e9 - pub))  # equal bytes: nearest
        stamp_err.append(pub - sent.t_sent * 1e9)
        if m.arbitration_id == WHEEL_SPEEDS_ID:  # type: ignore[attr-defined]
            speed_err.append(m.speed_mps - sent.speed)  # type: ignore[attr-defined]
        else:
            assert m.arbitration_id == YAW_RATE_ID  # type: ignore[attr-defined]
            yaw_err.append(m.yaw_rate_rps - sent.yaw_rate)  # type: ignore[attr-defined]
    assert np.max(np.abs(speed_err)) <= 0.005 / 3.6 + 1e-9
    assert np.max(np.abs(yaw_err)) <= np.radians(0.005) + 1e-9
    # stamped on receipt: within 2 ms, a frame received while both cores are busy later
    assert np.percentile(np.abs(stamp_err), 99) < 2e6 and np.max(np.abs(stamp_err)) < 20e6
    # fixes: the true position, stamped with the fix instant (the receiver's UTC is 2.5 s
    # off the host's wall clock: only the one-way estimator's mapping can get this right)
    epochs = {round(t.utc_s, 2): t for t in rig.gnss.truth}
    stamp_err, recv_delay = [], []
    for log_time, pub, m in fixes:
        meta = {kv.key: kv.value for kv in m.metadata}  # type: ignore[attr-defined]
        t = epochs[round(float(meta["utc_s"]), 2)]
        assert m.latitude == pytest.approx(t.latitude, abs=2e-9)  # type: ignore[attr-defined]
        assert m.longitude == pytest.approx(t.longitude, abs=3e-9)  # type: ignore[attr-defined]
        assert m.altitude == pytest.approx(t.altitude, abs=6e-4)  # type: ignore[attr-defined]
        assert meta["quality"] == "1" and meta["satellites"] == "14"
        stamp_err.append(pub * 1e-9 - t.t)
        recv_delay.append(log_time * 1e-9 - t.t)
    stamp_ms, delay_ms = np.array(stamp_err) * 1e3, np.array(recv_delay) * 1e3
    assert np.all(delay_ms > GNSS_LATENCY_S * 1e3)
    # the estimator needs some fixes: the first are as late as their receipt (less the
    # latency), then the earliest receipts set the line and the jitter is filtered out
    # nor can it beat the earliest receipt so far: on a busy host even that comes some ms
    # late, and a fix received later with less delay cannot move the stamps before it
    floor = np.maximum(np.minimum.accumulate(delay_ms) - GNSS_LATENCY_S * 1e3, 0.0)
    settled = (stamp_ms - floor)[10:]
    assert -2.0 < np.median(settled) < 2.0, (floor, stamp_ms)
    assert np.max(np.abs(settled)) < 5.0, (floor, stamp_ms)
    assert np.ptp(stamp_ms[10:]) < np.ptp(delay_ms[10:]), stamp_ms
    assert np.max(np.abs(stamp_ms)) < np.max(delay_ms) - GNSS_LATENCY_S * 1e3 + 1.0, stamp_ms
    # the devices in the status and the metadata
    status = {d.name: d for d in log["/acq/status"][-1][2].devices}  # type: ignore[attr-defined]
    assert (status["vehicle"].kind, status["gnss"].kind) == ("can", "gnss")
    assert status["vehicle"].connected and status["vehicle"].rate_hz == pytest.approx(100, rel=0.2)
    assert status["gnss"].connected and status["gnss"].rate_hz == pytest.approx(10, rel=0.2)
    # the bad frame and the bad sentence: counted, and recorded raw as they came
    assert status["vehicle"].protocol_errors == status["gnss"].protocol_errors == 1
    assert sum(m.data == b"\x01\x02\x03" for _, _, m in can) == 1  # type: ignore[attr-defined]
    meta = read_metadata(path)
    assert "device.vehicle" in meta and "device.gnss" in meta
    # acq info knows the topics by their log times; replay serves the car and receiver too
    summary = {c.topic: c for c in info(path).channels}
    assert summary["/vehicle/odometry"].rate_hz == pytest.approx(100, rel=0.05)
    assert summary["/gnss/fix"].schema == "foxglove.LocationFix"
    # bursts are not gaps (taken for gaps, each burst would be one: hundreds); a busy host
    # may hold the simulated car's thread up for a few of its 10 ms periods: the gaps the
    # car itself left between its frames, by the same rule, are not the recorder's
    stamps = [stamp(m) for _, _, m in can]
    sent = sorted(round(s.t_sent * 1e9) for s in rig.car.truth)
    sent = [t for t in sent if min(stamps) - 50e6 <= t <= max(stamps) + 50e6]
    _, car_gaps = gaps(sent)
    assert len(summary["/vehicle/can"].gaps) <= len(car_gaps) + 3, car_gaps
    assert len(summary["/gnss/raw"].gaps) <= 3
    assert sorted(replay.load_session([path]).devices) == ["gnss", "laser", "vehicle"]
    # read back as arrays
    vehicle = read_vehicle([path])
    o, f = vehicle.odometry, vehicle.fixes
    assert len(o) == len(odo) and len(f) == len(fixes) and not vehicle.notes
    # each fix once (two may share a stamp: the clock's envelope dropping by a period
    # within the first fixes, which a loaded host held up)
    assert np.all(np.diff(o.t_ns) >= 0) and np.all(np.diff(f.t_ns) >= 0)
    assert np.unique(f.utc_s).size == len(f)
    assert np.all(np.isfinite(o.speed)) and np.all(np.isfinite(o.yaw_rate))
    assert o.speed_measured.sum() == len(speed_err) and o.yaw_rate_measured.sum() == len(yaw_err)
    assert not np.any(o.speed_measured & o.yaw_rate_measured)
    wheels = o.wheel_speeds[o.speed_measured]
    np.testing.assert_allclose(o.speed[o.speed_measured], wheels.mean(axis=1), atol=1e-12)
    # interpolated rows (at yaw messages) lie within the true speed's resolution
    true_speed = np.array([rig.car.motion(t * 1e-9)[0] for t in o.t_ns[~o.speed_measured]])
    assert np.max(np.abs(o.speed[~o.speed_measured] - true_speed)) < 0.01
    speed_at, yaw_at = o.at(o.t_ns[o.yaw_rate_measured])
    np.testing.assert_allclose(yaw_at, o.yaw_rate[o.yaw_rate_measured])  # measured there
    np.testing.assert_allclose(speed_at, o.speed[o.yaw_rate_measured])  # interpolated there
    np.testing.assert_allclose(np.diff(f.utc_s), 0.1, atol=1e-6)
    assert np.all(f.quality == 1) and np.all(f.hdop == 0.7) and np.all(f.satellites == 14)
    assert np.all(np.isfinite(f.lat))
    assert np.all(np.isfinite(f.course))  # the fix whose RMC was lost has VTG's course


def test_a_dbc_without_the_signals_is_a_configuration_error(
    rig: VehicleRig, tmp_path: Path
) -> None:
    cfg = rig.config(tmp_path, yaw_rate="YAW_RATE.GIER_RATE")
    with pytest.raises(RecorderError, match="message YAW_RATE has no signal 'GIER_RATE'"):
        Recorder(cfg)
