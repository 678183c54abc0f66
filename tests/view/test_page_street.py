"""`acq view` on the simulated street in headless Chromium (tests/browser.py): a drive of
the simulated rig coloured by `acq colorize`'s core is drawn in the street's own colours,
and the distance tool measures a known distance of the street (between two of its true
surface points) within 1 cm. The drive's ranges are exact and its body does not vibrate,
so that the cloud's points are the street's (the scanner's 1 cm range noise would be the
cloud's error, not the tool's)."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from acq.camera import calibfile
from acq.cloud import colorize
from acq.cloud.chunks import ChunkResult
from acq.sim.drive_log import DriveTruth, write_drive_log
from acq.sim.world import default_rig
from acq.view.server import ViewServer
from tests.browser import Browser
from tests.view.test_page import BACKGROUND, READY

CM = 0.01


@dataclass(frozen=True)
class Street:
    cloud: Path
    truth: DriveTruth
    xyz: np.ndarray  # the cloud's points, m (its world frame: the odometry's)
    scan: np.ndarray  # each point's scan and step: its true surface point truth.points[scan, step]
    step: np.ndarray


@pytest.fixture(scope="module")
def street(tmp_path_factory: pytest.TempPathFactory) -> Street:
    """A 2 s drive of the one-camera rig with exact ranges and no vibration, coloured."""
    from plyfile import PlyData

    folder = tmp_path_factory.mktemp("street")
    rig = dataclasses.replace(default_rig(), range_noise=0.0)
    truth = write_drive_log(folder, 2.0, pattern_at=None, vibration_rad=0.0, rig=rig)
    calib = folder / "calib.yaml"
    calibfile.save(truth.calibration, calib)
    cloud = folder / "cloud.ply"
    results: list[ChunkResult] = []
    colorize.run(truth.files, calibfile.load(calib), cloud, results=results)
    v = PlyData.read(str(cloud))["vertex"].data
    xyz = np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float64)
    scan = np.concatenate([r.scan for r in results]).astype(np.int64)
    step = np.concatenate([r.step for r in results]).astype(np.int64)
    assert (scan == v["scalar_scan"]).all()  # the file holds the results in their order
    return Street(cloud, truth, xyz, scan, step)


def _open(browser: Browser, server: ViewServer) -> None:
    browser.open(server.url)
    browser.wait_for(READY, timeout_s=60)
    assert browser.evaluate("window.acqError ?? null") is None


def test_the_street_is_drawn_in_its_own_colours(browser: Browser, street: Street) -> None:
    # the colours of the street's surfaces where the scanner hit them (the simulator's
    # truth, BGR): facades, their windows and frames, sidewalk tiles, road, cars...
    palette = np.unique(street.truth.colours.reshape(-1, 3), axis=0)[:, ::-1].astype(np.int32)
    with ViewServer([street.cloud]) as server:
        _open(browser, server)
        image = browser.screenshot().astype(np.int32)
        assert browser.errors == [], browser.console
        # the same cloud in another colour mode: the test tells colours apart
        browser.evaluate(
            "(() => { const s = document.getElementById('colour-mode'); s.value = 'scan';"
            " s.dispatchEvent(new Event('change')); })()"
        )
        time.sleep(0.3)
        other = browser.screenshot().astype(np.int32)

    def street_share(shot: np.ndarray) -> tuple[float, int]:
        drawn = shot[(np.abs(shot - np.array(BACKGROUND)).max(axis=2) > 6)]
        near = np.abs(drawn[:, None, :] - palette[None, :, :]).max(axis=2).min(axis=1)
        return float((near <= 32).mean()), len(drawn)

    share, drawn = street_share(image)
    assert drawn > 0.05 * image.shape[0] * image.shape[1]  # the street fills the view
    assert share > 0.8, f"{share:.1%} of the drawn pixels in the street's colours"
    assert street_share(other)[0] < share - 0.3


def test_the_distance_tool_measures_the_street_within_a_centimetre(
    browser: Browser, street: Street
) -> None:
    # two points of one scan on a facade, about 0.5 m apart
    middle = int(np.median(street.scan))
    on = np.flatnonzero((street.scan == middle) & (street.xyz[:, 2] > 1.0))
    a = on[np.argmin(np.abs(street.xyz[on, 2] - 1.5))]
    b = on[np.argmin(np.abs(np.linalg.norm(street.xyz[on] - street.xyz[a], axis=1) - 0.5))]
    A, B = street.xyz[a], street.xyz[b]
    # the known distance: between the street's true surface points the two returns hit
    # (a distance: the same in the street's frame as in the cloud's)
    TA, TB = street.truth.points[street.scan[[a, b]], street.step[[a, b]]].astype(np.float64)
    known = float(np.linalg.norm(TA - TB))
    assert 0.4 < known < 0.6
    with ViewServer([street.cloud]) as server:
        _open(browser, server)
        # the eye 1.5 m from the facade, in the street, level with the two points
        middle_point = (A + B) / 2
        eye = middle_point - np.array([0.0, 1.5, 0.0])
        browser.evaluate(f"window.acqLod.look({eye.tolist()}, {middle_point.tolist()})")
        time.sleep(0.5)
        browser.evaluate("document.getElementById('measure').click()")
        for p in (A, B):
            x, y = browser.evaluate(f"window.acqProject({p.tolist()})")
            browser.click(x, y)
        measured = browser.wait_for("window.acqMeasured?.distance", timeout_s=10)
        assert browser.errors == [], browser.console
    assert abs(measured - known) < CM, (measured, known)
