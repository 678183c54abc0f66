"""A drive (.mcap) in `acq view`'s page in headless Chromium (tests/browser.py): its path
and camera frustums drawn in their colours with its cloud, the frame a clicked point was
coloured from shown with the ring at the pixel the colouring used (the truth kept by
`acq colorize`), walk mode moving the eye along the trajectory, and a cloud coloured in
the background coming into the page."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from acq.sim.drive_log import DriveTruth
from acq.view.drive import CAMERA_COLOURS
from acq.view.server import ViewServer
from tests.browser import Browser
from tests.log_rewrite import mcap_copy
from tests.view.drive_files import ColouredDrive, coloured_drive
from tests.view.test_page import BACKGROUND, READY, _share

FRUSTUM = tuple(int(CAMERA_COLOURS[0][k : k + 2], 16) for k in (1, 3, 5))  # the camera's
RING = (0x00, 0xFF, 0x66)
COLOURED, NOT_COLOURED = (
    (46, 204, 64),
    (255, 65, 54),
)  # colour_modes.js's  # the frame panel's ring (viewer.css)
UP = np.array([0.0, 0.0, 1.7])  # walk mode's eye above the trajectory (walk.js EYE_M)


@pytest.fixture(scope="module")
def drive(
    short_drive: tuple[DriveTruth, Path], tmp_path_factory: pytest.TempPathFactory
) -> ColouredDrive:
    return coloured_drive(short_drive, tmp_path_factory.mktemp("page_drive"))


def _open(browser: Browser, server: ViewServer, cloud: bool = True) -> None:
    browser.open(server.url)
    browser.wait_for(READY, timeout_s=60)
    assert browser.evaluate("window.acqError ?? null") is None
    if cloud:
        browser.wait_for("window.acqDriveCloud?.[0]", timeout_s=60)
        time.sleep(0.2)  # drawn at the next frame


def test_the_drive_is_drawn_with_its_path_frustums_and_cloud(
    browser: Browser, drive: ColouredDrive
) -> None:
    with ViewServer([drive.log]) as server:
        _open(browser, server)
        assert browser.evaluate("window.acqDriveCloud[0]") == "cloud.ply"
        shown = browser.screenshot()
        assert browser.errors == [], browser.console
        # the frustums' pixels in their camera's colour, the white path, the street
        assert _share(shown, FRUSTUM, tolerance=10) > 0.0003
        # ... and where the frustums are: by their apexes, the camera's poses
        poses = server.drives[0].frustums()[0]["p"]
        at = np.array([browser.evaluate(f"window.acqProject({p})") for p in poses])
        ys, xs = np.nonzero((np.abs(shown.astype(int) - FRUSTUM) <= 10).all(axis=2))
        near = np.hypot(xs[:, None] - at[:, 0], ys[:, None] - at[:, 1]).min(axis=1)
        assert (near < 30).mean() > 0.95
        assert _share(shown, (255, 255, 255), tolerance=10) > 0.0002
        browser.evaluate("document.querySelector('#layers input').click()")  # hidden
        time.sleep(0.2)
        hidden = browser.screenshot()
        assert _share(hidden, FRUSTUM, tolerance=10) == 0.0
        # the cloud went with them (the street drawn over a twentieth of the view and more)
        drawn = _share(hidden, BACKGROUND, tolerance=4) - _share(shown, BACKGROUND, tolerance=4)
        assert drawn > 0.05


def test_the_drives_cloud_takes_a_colour_mode_from_its_attributes(
    browser: Browser, drive: ColouredDrive
) -> None:
    """The drive's cloud came with its positions and colours only; "coloured or not"
    fetches its other attributes (cloud-attributes.bin) and draws its points coloured
    green, those no frame coloured red."""
    with ViewServer([drive.log]) as server:
        _open(browser, server)
        assert _share(browser.screenshot(), COLOURED, tolerance=6) == 0.0
        browser.evaluate(
            "(() => { const c = document.getElementById('colour-mode'); c.value = 'coloured';"
            " c.dispatchEvent(new Event('change')); })()"
        )
        browser.wait_for("window.acqColourMode === 'coloured'", timeout_s=30)
        browser.evaluate("document.getElementById('panel').style.visibility = 'hidden'")
        shown = browser.screenshot()
        fetched = browser.evaluate(
            "performance.getEntriesByType('resource').map((e) => new URL(e.name).pathname)"
            ".filter((p) => p.startsWith('/data/0/cloud'))"
        )
        assert browser.errors == [], browser.console
    assert fetched == ["/data/0/cloud.bin", "/data/0/cloud-attributes.bin"]
    coloured = drive.frame >= 0
    assert coloured.any()
    assert _share(shown, COLOURED, tolerance=6) > 0.01
    if not coloured.all():
        assert _share(shown, NOT_COLOURED, tolerance=6) > 0


def _ring_centre(image: np.ndarray, x: float, y: float) -> tuple[float, float]:
    """The centre of the ring-coloured pixels within 20 px of (x, y)."""
    x0, y0 = round(x) - 20, round(y) - 20
    block = image[y0 : y0 + 41, x0 : x0 + 41].astype(np.int32)
    ys, xs = np.nonzero((np.abs(block - RING) <= 40).all(axis=2))
    assert len(xs) > 20, "no ring drawn there"
    return x0 + float(xs.mean()), y0 + float(ys.mean())


def test_a_click_shows_the_frame_with_the_point_ringed_at_its_pixel(
    browser: Browser, drive: ColouredDrive
) -> None:
    assert drive.cloud is not None
    from plyfile import PlyData

    xyz = np.array(PlyData.read(str(drive.cloud))["vertex"].data[["x", "y", "z"]].tolist())
    with ViewServer([drive.log]) as server:
        _open(browser, server)
        shown = "!document.getElementById('{}').closest('.control').hidden"
        assert browser.evaluate(shown.format("show-frame")) and browser.evaluate(
            shown.format("walk")
        )
        browser.evaluate("document.getElementById('show-frame').click()")
        # a facade point the colouring coloured, drawn clear of the panel
        candidates = np.flatnonzero((drive.frame >= 0) & (xyz[:, 2] > 2.0))
        for row in candidates[:: max(1, candidates.size // 200)]:
            x, y = browser.evaluate(f"window.acqProject({xyz[row].tolist()})")
            if 340 < x < 780 and 40 < y < 580:
                break
        browser.click(x, y)
        answer = browser.wait_for("window.acqFrame?.ring && window.acqFrame", timeout_s=30)
        picked = answer["row"]
        # the pixel of the point picked: the colouring's own, found independently of the server
        assert answer["camera"] == "camera" and answer["frame"] == drive.frame[picked]
        np.testing.assert_allclose(answer["pixel"], drive.uv[picked], atol=1e-3)
        # the point under the click (the tools pick within 6 px, the nearest to the eye)
        drawn_at = browser.evaluate(f"window.acqProject({xyz[picked].tolist()})")
        assert np.hypot(drawn_at[0] - x, drawn_at[1] - y) <= 6.5
        time.sleep(0.2)
        shown = browser.screenshot()
        box = browser.evaluate(
            "(() => { const image = document.getElementById('frame-image');"
            " const r = image.getBoundingClientRect();"
            " return [r.left, r.top, r.width, image.naturalWidth]; })()"
        )
        left, top, width, natural = box
        assert natural == 780
        scale = width / 780
        expected = (left + drive.uv[picked][0] * scale, top + drive.uv[picked][1] * scale)
        centre = _ring_centre(shown, *expected)
        assert np.hypot(centre[0] - expected[0], centre[1] - expected[1]) < 1.5
        caption = browser.evaluate("document.getElementById('frame-caption').textContent")
        assert f"camera, frame {answer['frame']}:" in caption
        assert f"pixel {answer['pixel'][0]:.1f}, {answer['pixel'][1]:.1f}" in caption
        assert browser.errors == [], browser.console


def _along(path: np.ndarray, s: float) -> np.ndarray:
    """The point of the polyline ``path`` at ``s`` m along it."""
    cumulative = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    return np.array([np.interp(s, cumulative, path[:, k]) for k in range(3)])


def test_walk_mode_moves_the_eye_along_the_trajectory(
    browser: Browser, drive: ColouredDrive
) -> None:
    with ViewServer([drive.log]) as server:
        path = server.drives[0].path()
        _open(browser, server)
        orbit = browser.screenshot()
        browser.evaluate("document.getElementById('walk').click()")
        walk = browser.wait_for("window.acqWalk")
        np.testing.assert_allclose(walk["eye"], path[0] + UP, atol=1e-6)
        assert np.dot(walk["looking"], [1, 0, 0]) > 0.95  # the drive goes +x
        browser.evaluate("window.dispatchEvent(new KeyboardEvent('keydown', {key: 'ArrowUp'}))")
        browser.wait_for("window.acqWalk.at > 2", timeout_s=10)
        browser.evaluate("window.dispatchEvent(new KeyboardEvent('keyup', {key: 'ArrowUp'}))")
        walk = browser.evaluate("window.acqWalk")
        np.testing.assert_allclose(walk["eye"], _along(path, walk["at"]) + UP, atol=1e-6)
        ahead = _along(path, walk["at"] + 1) - _along(path, walk["at"])
        assert np.dot(walk["looking"], ahead / np.linalg.norm(ahead)) > 0.95
        # the slider puts the eye anywhere along the drive; S walks back
        browser.evaluate(
            "(() => { const s = document.getElementById('walk-at'); s.value = '6';"
            " s.dispatchEvent(new Event('input')); })()"
        )
        assert browser.evaluate("window.acqWalk.at") == 6
        browser.evaluate("window.dispatchEvent(new KeyboardEvent('keydown', {key: 's'}))")
        browser.wait_for("window.acqWalk.at < 5", timeout_s=10)
        browser.evaluate("window.dispatchEvent(new KeyboardEvent('keyup', {key: 's'}))")
        walking = browser.screenshot()
        assert np.abs(walking.astype(int) - orbit).mean() > 5  # another view
        browser.evaluate("document.getElementById('walk').click()")  # back to orbit
        assert browser.evaluate("window.acqWalk") is None
        time.sleep(0.2)
        back = browser.screenshot()
        assert np.abs(back.astype(int) - orbit).mean() < 1
        assert browser.errors == [], browser.console


def test_a_cloud_coloured_in_the_background_comes_into_the_page(
    browser: Browser, short_drive: tuple[DriveTruth, Path], tmp_path: Path
) -> None:
    bare = coloured_drive(short_drive, tmp_path / "bare", cloud_name=None)
    with ViewServer([bare.log], cache=tmp_path / "cache") as server:
        _open(browser, server, cloud=False)
        name = browser.wait_for("window.acqDriveCloud?.[0]", timeout_s=60)
        assert name.startswith(bare.log.stem) and name.endswith(".ply")
        status = browser.evaluate("document.getElementById('drives').textContent")
        assert f"cloud {name}" in status
        assert browser.errors == [], browser.console
    bare.calib.unlink()  # no calibration: the path alone, and the page says why
    with ViewServer([bare.log]) as server:
        _open(browser, server, cloud=False)
        status = browser.wait_for(
            "document.getElementById('drives').textContent.includes('no cloud beside') && "
            "document.getElementById('drives').textContent"
        )
        assert "no cloud beside the log, and no calibration to colour one" in status
        assert (
            "no calibration (calib.yaml beside the log, or --calib): the trajectory alone" in status
        )
        assert browser.errors == [], browser.console


def test_a_drive_without_odometry_shows_its_cloud_when_it_is_coloured(
    browser: Browser, drive: ColouredDrive, tmp_path: Path
) -> None:
    """No trajectory: nothing to draw at first (no path, no frustums), the page says why,
    then frames the cloud the server colours in the laser frame."""
    log = tmp_path / "no_odometry.mcap"
    mcap_copy(drive.log, log, keep=lambda topic: "odometry" not in topic)
    with ViewServer([log], calib=drive.calib, cache=tmp_path / "cache") as server:
        _open(browser, server, cloud=False)
        status = browser.evaluate("document.getElementById('drives').textContent")
        assert "no trajectory (the log has no CAN odometry or GNSS fixes)" in status
        browser.wait_for("window.acqDriveCloud?.[0]", timeout_s=60)
        time.sleep(0.2)
        shown = browser.screenshot()
        assert browser.errors == [], browser.console
    # the cloud (the rig's profiles, piled in the laser frame) framed right of the panel
    assert 1 - _share(shown[:, 320:], BACKGROUND, tolerance=4) > 0.005
