"""`acq sim rig` -> `acq record` -> `acq colorize`, the README's recording walkthrough: the
whole simulated rig in its own process (the scanner on TCP, both cameras, the car on
udp_multicast, the GNSS receiver on TCP), recorded for a few seconds by a recorder in this
process from the rig.yaml it wrote, then coloured with the calib.yaml it wrote from the
recorded CAN odometry and GNSS fixes: a cloud that moves with the car, coloured from
both cameras."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from plyfile import PlyData

from acq.cli import main as acq_main
from acq.log.vehicle_log import read_vehicle

# drives simulated devices in real time: run alone (`make test`)
pytestmark = pytest.mark.realtime

RECORD_S = 3.0
PRERENDER_S = 7.0  # the rig's start, the recorder's and RECORD_S, with a little to spare
START_TIMEOUT_S = 180.0  # the cameras render their frames first: long on a loaded machine


def _start_rig(out: Path) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "acq.cli", "sim", "rig", "--out", str(out),
         "--prerender", repr(PRERENDER_S), "--duration", "300"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip


def _wait_ready(rig: subprocess.Popen[str], config: Path) -> None:
    deadline = time.monotonic() + START_TIMEOUT_S
    while not config.exists():
        if rig.poll() is not None:
            out = rig.stdout.read() if rig.stdout else ""
            pytest.fail(f"acq sim rig ended with {rig.returncode}: {out}")
        assert time.monotonic() < deadline, "acq sim rig: no rig.yaml"
        time.sleep(0.2)


def test_sim_rig_record_colorize_gives_a_moving_two_camera_cloud(tmp_path: Path) -> None:
    out = tmp_path / "rig"
    config, calib = out / "rig.yaml", out / "calib.yaml"
    rig = _start_rig(out)
    try:
        _wait_ready(rig, config)
        data = yaml.safe_load(config.read_text())
        assert data["can"]["interface"] == "udp_multicast" and "gnss" in data
        assert [c["name"] for c in data["cameras"]] == ["left", "right"]
        logs = tmp_path / "logs"
        code = acq_main(
            ["record", "-c", str(config), "--out", str(logs), "--duration", repr(RECORD_S)]
        )
        assert code == 0
    finally:
        rig.send_signal(signal.SIGTERM)
        printed, _ = rig.communicate(timeout=30)
    assert rig.returncode == 0, printed
    assert "record it: acq record -c" in printed
    assert not config.exists()  # its devices are gone
    parts = sorted(logs.glob("rig_*.mcap"))
    assert len(parts) == 1
    vehicle = read_vehicle(parts)
    assert len(vehicle.odometry) > 50 * RECORD_S  # the car's frames reached the recorder
    assert len(vehicle.fixes) > 5 * RECORD_S

    ply = tmp_path / "cloud.ply"
    assert acq_main(["colorize", str(parts[0]), "--calib", str(calib), "-o", str(ply)]) == 0
    v = PlyData.read(str(ply))["vertex"].data
    coloured = v["scalar_coloured"].astype(bool)
    assert coloured.mean() > 0.95  # 47.6 % without a trajectory
    assert len(np.unique(v["scalar_camera"][coloured])) == 2  # both cameras coloured
    # the cloud moves with the car: the profiles' centres at the start and at the end lie
    # as far apart as the odometry drove (a cloud placed without a trajectory: ~0 m)
    scans = v["scalar_scan"]
    xyz = np.stack([v["x"], v["y"]], axis=1)
    first, last = np.unique(scans)[[0, -1]]
    ends = [xyz[(scans >= s) & (scans < s + 20)].mean(axis=0) for s in (first, last - 19)]
    moved = float(np.linalg.norm(ends[1] - ends[0]))
    t = vehicle.odometry.t_ns
    t_scan = v["scalar_time"]
    span_s = float(t_scan[scans >= last - 9].mean() - t_scan[scans < first + 10].mean())
    driven = float(np.median(vehicle.odometry.speed)) * span_s
    assert len(t) and driven > 5.0
    assert moved == pytest.approx(driven, rel=0.15)
    assert os.path.exists(tmp_path / "cloud_preview.png")


def test_sim_rig_writes_into_no_folder_of_anyone_else(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "rig.yaml").write_text("mine")
    assert acq_main(["sim", "rig", "--out", str(tmp_path), "--duration", "1"]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rig.yaml"]
    assert (tmp_path / "rig.yaml").read_text() == "mine"


def test_sim_rig_never_overwrites_a_calibration_put_in_its_folder(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A rig's folder (its mark) where the user then saved their own calib.yaml:
    refused before the rig starts, the file as it was."""
    from acq.cli.sim import RIG_FILES, RIG_MARK
    from acq.sim.out_folder import claim_folder

    claim_folder(tmp_path, RIG_MARK, "an acq sim rig", RIG_FILES)
    (tmp_path / "calib.yaml").write_text("mine")
    capsys.readouterr()
    args = ["--out", str(tmp_path), "--duration", "0.1", "--prerender", "1"]
    assert acq_main(["sim", "rig", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "calib.yaml" in err[0] and "not overwritten" in err[0]
    assert (tmp_path / "calib.yaml").read_text() == "mine"
