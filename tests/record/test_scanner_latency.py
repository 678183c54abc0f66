"""``latency_s`` left out of the configuration: measured, and said how, for a SICK scanner
(from its scans' own time of transmission) recording from the simulated LMS111 over TCP
on 127.0.0.1."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from acq.log import format_info, info
from acq.record import config as configfile
from acq.record.recorder import Recorder
from acq.sim.cola_device import ColaDevice
from acq.sim.scanner_models import MODELS
from acq.sim.transport import TcpDeviceServer
from tests.sim_rig import read_log

pytestmark = pytest.mark.realtime


def test_sick_latency_from_its_telegrams_puts_stamps_on_the_truth(tmp_path: Path) -> None:
    device = ColaDevice(MODELS["lms111"])
    with TcpDeviceServer(device) as server:
        path = tmp_path / "rig.yaml"
        path.write_text(yaml.safe_dump({
            "version": 1,
            "scanners": [{"name": "laser", "driver": "sick", "url": server.url.replace("socket://", "tcp://")}],
            "output": {"dir": str(tmp_path / "logs")},
        }))  # fmt: skip
        cfg = configfile.load(path)
        assert cfg.scanners[0].latency_s == "auto"
        assert Recorder(cfg, duration_s=4.0).run() == 0
        sent = {s.ticks[0]: s for s in list(device.history)}
    (log_path,) = sorted((tmp_path / "logs").glob("*.mcap"))
    log = read_log(log_path)
    truth = [sent[m.device_ticks[0]].t0 for _, _, m in log["/laser/raw"]]
    stamps = [p * 1e-9 for _, p, _ in log["/laser/scan"]]
    err = np.array(stamps) - np.array(truth)
    # the first 40 scans are stamped before the latency is known; then late by what
    # follows the sending: the transport and this host's reading (1.0-1.1 ms here)
    assert 0.0 < float(np.median(err[60:])) < 2e-3, np.percentile(err[60:], [5, 50, 95])
    laser = next(d for d in info(log_path).devices if d.name == "laser")
    assert laser.latency_s == pytest.approx(0.02, abs=1e-4)  # the LMS111 sends a scan after it
    text = format_info(info(log_path)).splitlines()
    line = next(x for x in text if x.lstrip().startswith("latency"))
    assert "laser: 20.00 ms (auto: each scan's time of transmission" in line, line
