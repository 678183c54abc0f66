"""`acq record` against a hostile time base: a ``chronyc`` on PATH (a script standing
in for chrony's client, the one thing of the host the test cannot make chronyd answer)
that prints, in turn, a tracking line whose reference ID and stratum no report can hold
and one with a 5 MB field. A good simulated UTM-30LX over TCP records throughout; each
reading is recorded with chrony absent and a short reason, never failing the writer."""

from __future__ import annotations

import os
import subprocess
import sys
from contextlib import closing
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader

from acq.sim.scanner_models import MODELS
from acq.sim.scip_device import ScipDevice
from acq.sim.transport import TcpDeviceServer
from tests.sim_rig import read_log

# drives a simulated scanner in real time: run alone (`make test`)
pytestmark = pytest.mark.realtime

ROOT = Path(__file__).resolve().parents[2]
TAIL = "1796194607.25,0,0,0,0,0,0,0,0,1.0,Normal"
HOSTILE_CHRONYC = f"""#!/bin/sh
n=$(cat "$0.count" 2>/dev/null || echo 0)
echo $((n + 1)) > "$0.count"
if [ $((n % 2)) = 0 ]; then
  echo "FFFFFFFFFFFFFFFFFFFF,TEST,-1,{TAIL}"
else
  printf '54455354,'; head -c 5000000 /dev/zero | tr '\\0' x; echo ",1,{TAIL}"
fi
"""


DURATION_S = 4.0


def _record(scanner_url: str, tmp_path: Path) -> Path:
    """``acq record`` of the scanner for :data:`DURATION_S` with the hostile chronyc first
    on PATH: its log, after checking the recorder exited 0 having asked chronyc twice."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    chronyc = bin_dir / "chronyc"
    chronyc.write_text(HOSTILE_CHRONYC)
    chronyc.chmod(0o755)
    cfg = tmp_path / "rig.yaml"
    config = {
        "version": 1,
        "scanners": [{"name": "laser", "driver": "hokuyo", "url": scanner_url}],
        "output": {"dir": str(tmp_path / "logs")},
    }
    cfg.write_text(yaml.safe_dump(config))
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}"}
    done = subprocess.run(
        [sys.executable, "-m", "acq.cli", "record", "-c", str(cfg), "--duration", str(DURATION_S)],
        cwd=ROOT, env=env, capture_output=True, timeout=60,
    )  # fmt: skip
    err = done.stderr.decode(errors="replace")
    assert done.returncode == 0, err
    assert "Traceback" not in err and "Value out of range" not in err
    assert int((bin_dir / "chronyc.count").read_text()) >= 2, "both answers were read"
    (path,) = sorted((tmp_path / "logs").glob("*.mcap"))
    return path


def test_hostile_chronyc_readings_are_contained_and_bounded(tmp_path: Path) -> None:
    with closing(TcpDeviceServer(ScipDevice(MODELS["utm-30lx"])).start()) as scanner:
        path = _record(scanner.url, tmp_path)
    log = read_log(path)
    scans = np.array([t for t, _, _ in log["/laser/scan"]]) * 1e-9
    assert len(scans) > 50 and scans[-1] - scans[0] > DURATION_S - 2.0  # recorded throughout
    readings: list[Any] = [m for _, _, m in log["/acq/timebase"]]
    assert len(readings) >= 2
    reasons = [a for m in readings for a in m.absent if a.startswith("chrony: ")]
    assert not any(m.HasField("chrony") for m in readings)
    assert "chrony: chronyc tracking: reference ID 'FFFFFFFFFFFFFFFFFFFF' is not in" in reasons[0]
    assert any("chronyc printed more than 65536 bytes" in r for r in reasons), reasons
    with path.open("rb") as f:
        sizes = [len(m.data) for _, _, m in make_reader(f).iter_messages(topics=["/acq/timebase"])]
    assert max(sizes) < 1000, f"a time base record of {max(sizes)} bytes"
    print(f"{len(sizes)} time base records, {sum(sizes)} bytes in all, {max(sizes)} at most")
