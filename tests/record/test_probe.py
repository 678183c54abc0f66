"""`acq probe scanner` against every simulated model, over TCP (and a pty for the serial
Hokuyos): identity, geometry equal to the model's, scans as JSON lines."""

from __future__ import annotations

import itertools
import json

import pytest

from acq import cli
from acq.sim.devices import make_scanner, serve_scanner
from acq.sim.scanner_models import MODELS

# drives simulated devices in real time: run alone (`make test`)
pytestmark = pytest.mark.realtime

CASES = [(name, False) for name in MODELS] + [
    (name, True) for name, m in MODELS.items() if m.serial_port
]


@pytest.mark.parametrize(
    ("name", "pty"), CASES, ids=[f"{n}-{'pty' if p else 'tcp'}" for n, p in CASES]
)
def test_probe_reads_every_simulated_model(
    name: str, pty: bool, capsys: pytest.CaptureFixture[str]
) -> None:
    m, device = make_scanner(name)
    server = serve_scanner(device, None, pty=pty)
    try:
        driver = "hokuyo" if m.vendor == "hokuyo" else "sick"
        code = cli.main(["probe", "scanner", "--driver", driver, "--url", server.url,
                         "--count", "3", "--json"])  # fmt: skip
    finally:
        server.close()
    out = capsys.readouterr()
    assert code == 0, out.err
    lines = [json.loads(line) for line in out.out.splitlines()]
    device_line, scans = lines[0]["device"], lines[1:]
    assert len(scans) == 3
    assert device_line["points"] == m.steps
    assert device_line["angle_min"] == pytest.approx(m.angle_min(), abs=1e-6)
    assert device_line["angle_increment"] == pytest.approx(m.angle_increment(), rel=1e-6)
    assert device_line["scan_period"] == pytest.approx(m.scan_period, rel=1e-3)
    for s in scans:
        assert len(s["ranges"]) == m.steps
        finite = [r for r in s["ranges"] if r is not None]
        assert finite, "the street gives echoes"
        assert all(m.range_min <= r <= m.range_max for r in finite)
    ticks = [s["device_ticks"][0] for s in scans]
    period_ticks = m.scan_period * m.clock_hz
    # one scan period apart on the device clock, within one tick of quantisation
    assert all(abs(b - a - period_ticks) <= 1 for a, b in itertools.pairwise(ticks)), ticks


def test_probe_reports_an_unreachable_device(capsys: pytest.CaptureFixture[str]) -> None:
    code = cli.main(["probe", "scanner", "--driver", "sick", "--url", "tcp://127.0.0.1:9",
                     "--count", "1"])  # fmt: skip
    assert code == 1
    assert "tcp://127.0.0.1:9" in capsys.readouterr().err
