"""The recorder with the simulated NMEA receiver on a pty (10 Hz, sentences 40 ms after
the fix instant plus jitter, its UTC the host's wall clock, as a receiver's is against a
disciplined host's) and a simulated UTM-30LX on TCP: with ``gnss.time`` auto, fixes are
stamped on their true instant when the host clock is disciplined, from their receipt
when it is not, and ``acq info`` says which and how late the fixes came.

The host clock's discipline is what :func:`acq.time.kernel_clock.read_kernel_clock`
says; the tests replace that function (the lowest layer, the kernel's ``adjtimex``
answer) with a chosen status: this host's clock is not disciplined and a test cannot
discipline it. The stamps from the fix time do not depend on when the sentences are
read, so a loaded machine does not move them; the receipt figures are bounded loosely.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import yaml

from acq.log import format_info, info
from acq.record import config as configfile
from acq.record.recorder import Recorder
from acq.sim.nmea_device import NmeaDevice, NmeaPtyServer
from acq.sim.scanner_models import MODELS
from acq.sim.scip_device import ScipDevice
from acq.sim.transport import TcpDeviceServer
from acq.time import kernel_clock
from tests.sim_rig import read_log

SECONDS = 2.5
LATENCY_S = 0.040  # the simulated receiver's constant delay (NmeaDevice's default)

SYNCHRONISED = kernel_clock.KernelClock(
    synchronised=True, state="ok", maxerror_s=0.0015, esterror_s=0.0001, offset_s=0.0,
    freq_ppm=1.2, pll=True, pps=False, tai_s=37,
)  # fmt: skip
UNSYNCHRONISED = dataclasses.replace(SYNCHRONISED, synchronised=False, state="unsynchronised")


@dataclasses.dataclass
class GnssRig:
    scanner: TcpDeviceServer
    gnss: NmeaDevice
    gnss_server: NmeaPtyServer

    def record(self, tmp_path: Path) -> Path:
        """``SECONDS`` recorded with gnss.time auto and latency_s 0 (the defaults)."""
        data = {
            "version": 1,
            "scanners": [{"name": "laser", "driver": "hokuyo", "url": self.scanner.url}],
            "gnss": {"url": self.gnss_server.url, "baudrate": 115200},
            "output": {"dir": str(tmp_path / "logs")},
        }
        (tmp_path / "rig.yaml").write_text(yaml.safe_dump(data))
        assert Recorder(configfile.load(tmp_path / "rig.yaml"), duration_s=SECONDS).run() == 0
        (path,) = sorted((tmp_path / "logs").glob("*.mcap"))
        return path

    def stamp_errors_ms(self, path: Path) -> tuple[np.ndarray, list[str]]:
        """Each fix's stamp minus its true instant, ms; each fix's stamp source."""
        truth = {round(t.utc_s, 2): t.t for t in self.gnss.truth}
        log = read_log(path)
        errors = []
        for _, pub, m in log["/gnss/fix"]:
            utc = float({kv.key: kv.value for kv in m.metadata}["utc_s"])  # type: ignore[attr-defined]
            errors.append((pub * 1e-9 - truth[round(utc, 2)]) * 1e3)
        sources = [m.stamp_source for _, _, m in log["/acq/timing/gnss"]]  # type: ignore[attr-defined]
        return np.array(errors), sources


@pytest.fixture(scope="module")
def rig() -> Iterator[GnssRig]:
    gnss = NmeaDevice(latency_s=LATENCY_S)
    r = GnssRig(
        TcpDeviceServer(ScipDevice(MODELS["utm-30lx"])).start(),
        gnss,
        NmeaPtyServer(gnss).start(),
    )
    try:
        yield r
    finally:
        r.gnss_server.close()
        r.scanner.close()


def test_a_disciplined_host_stamps_fixes_at_their_utc_fix_time(
    rig: GnssRig, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setattr(kernel_clock, "read_kernel_clock", lambda: SYNCHRONISED)
    with caplog.at_level(logging.INFO, logger="acq.record"):
        path = rig.record(tmp_path)
    startup = ("gnss: fixes stamped from their UTC fix time through the host clock (gnss.time "
               "auto: the host clock is synchronised (kernel maxerror 1.5 ms))")  # fmt: skip
    assert startup in caplog.text
    errors_ms, sources = rig.stamp_errors_ms(path)
    assert len(errors_ms) >= 15 and set(sources) == {"fix"}
    # on the truth (receipt stamping leaves them ~41 ms late, see below)
    assert np.max(np.abs(errors_ms)) < 2.0, errors_ms
    g = info(path).gnss_stamping
    assert g is not None and g.stamped == {"fix": len(errors_ms)}
    assert g.receipt_minus_fix_ms_median is not None
    assert LATENCY_S * 1e3 < g.receipt_minus_fix_ms_median < LATENCY_S * 1e3 + 40
    text = format_info(info(path))
    assert f"gnss time {len(errors_ms)} fixes: {len(errors_ms)} from their UTC fix time" in text
    assert (
        "latency   gnss: 0.00 ms (configured; not subtracted: fixes stamped from their UTC" in text
    )


def test_an_undisciplined_host_stamps_fixes_from_receipt(
    rig: GnssRig, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    monkeypatch.setattr(kernel_clock, "read_kernel_clock", lambda: UNSYNCHRONISED)
    with caplog.at_level(logging.INFO, logger="acq.record"):
        path = rig.record(tmp_path)
    startup = ("gnss: fixes stamped from their receipt, less latency_s 0.00 ms (gnss.time auto: "
               "the host clock is not synchronised (kernel: unsynchronised))")  # fmt: skip
    assert startup in caplog.text
    errors_ms, sources = rig.stamp_errors_ms(path)
    assert len(errors_ms) >= 15 and set(sources) == {"receipt"}
    # as late as the earliest receipts: the receiver's delay, which receipt cannot see
    assert np.median(errors_ms) > LATENCY_S * 1e3 - 1.0, errors_ms
    g = info(path).gnss_stamping
    assert g is not None and g.stamped == {"receipt": len(errors_ms)}
    assert g.receipt_minus_fix_ms_median is not None and g.receipt_minus_fix_ms_p5 is not None
    # the simulator's 40 ms and its jitter (3 ms on average); a loaded host adds some
    assert LATENCY_S * 1e3 < g.receipt_minus_fix_ms_p5 <= g.receipt_minus_fix_ms_median
    assert g.receipt_minus_fix_ms_median < LATENCY_S * 1e3 + 40
    text = format_info(info(path))
    assert f"gnss time {len(errors_ms)} fixes: {len(errors_ms)} from their receipt" in text
    assert "gnss time receipt - fix time (host UTC clock): median " in text
