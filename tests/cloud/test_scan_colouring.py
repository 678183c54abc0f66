"""The colouring core on plain arrays, one scan at a time (what the recorder runs live)
and several at once (what a chunk of ``acq colorize`` runs): no log, no session."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np
import pytest

from acq.camera import calibfile
from acq.cloud import scan_colouring, views
from acq.cloud.scan_colouring import Beams
from acq.geometry.transforms import Rigid
from acq.motion import Trajectory

CALIB = calibfile.load(Path(__file__).parents[2] / "config" / "sim_calib.yaml")
CAM = CALIB.cameras["camera"]
L2V = CALIB.laser_to_vehicle or Rigid.identity()
# 181 beams from +90 deg to -90 deg over 25 ms; the camera looks along the laser's -y:
# it sees the second half of each scan
BEAMS = Beams(angle_min=np.pi / 2, angle_increment=-np.pi / 180, time_increment=25e-3 / 180)
FRAME_NS = 40_000_000  # 25 Hz


def _jpeg(bgr: tuple[int, int, int]) -> bytes:
    """A frame of the camera model's size, all one colour."""
    image = np.zeros((CAM.model.height, CAM.model.width, 3), np.uint8)
    image[:] = bgr
    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    return bytes(data)


def _frames(n: int, offset_ns: int = 0) -> scan_colouring.CameraFrames:
    """``n`` frames 40 ms apart, frame k coloured (k * 20, 255 - k * 20, 100) in RGB."""
    stamps = np.arange(n, dtype=np.int64) * FRAME_NS
    jpegs = [_jpeg((100, 255 - 20 * k, 20 * k)) for k in range(n)]
    return scan_colouring.camera_frames("camera", CAM, stamps, jpegs, offset_ns, None)


def _ranges(scans: int) -> np.ndarray:
    """Scans of 181 beams, all 4 m (a cylinder of walls round the laser)."""
    return np.full((scans, 181), 4.0, dtype=np.float32)


def test_place_puts_each_return_at_its_beams_angle_and_time() -> None:
    ranges = _ranges(2)
    ranges[1, 5] = np.nan  # no return: not placed
    scan_ns = np.array([1_000, 26_000_000], dtype=np.int64)
    pts = scan_colouring.place(ranges, scan_ns, BEAMS, None, None, L2V)
    assert pts.time_ns.size == 2 * 181 - 1
    k = 90  # straight ahead
    first = np.flatnonzero((pts.scan == 0) & (pts.step == k))[0]
    assert pts.P_laser[first] == pytest.approx([4.0, 0.0, 0.0], abs=1e-9)
    assert pts.P_laser[np.flatnonzero(pts.step == 0)[0]] == pytest.approx([0, 4.0, 0], abs=1e-9)
    assert pts.time_ns[first] == 1_000 + round(k * BEAMS.time_increment * 1e9)
    assert np.all(np.diff(pts.time_ns) >= 0)
    np.testing.assert_array_equal(pts.P_world, pts.P_laser)  # no poses: laser frame


def test_place_with_poses_moves_each_point_with_the_rig_at_its_own_time() -> None:
    t = np.array([0, 1_000_000_000], dtype=np.int64)
    traj = Trajectory(t, np.stack([np.eye(3)] * 2), np.array([[0.0, 0, 0], [10.0, 0, 0]]))
    ranges = _ranges(1)
    pts = scan_colouring.place(ranges, np.array([500_000_000]), BEAMS, None, traj, L2V)
    expect = L2V.apply(pts.P_laser) + np.outer(pts.time_ns * 1e-8, [1.0, 0, 0])
    np.testing.assert_allclose(pts.P_world, expect, atol=1e-9)
    late = scan_colouring.place(ranges, np.array([3_000_000_000]), BEAMS, None, traj, L2V)
    assert not late.inside.any() and np.isnan(late.P_world).all()  # no pose: not placed


def test_camera_frames_applies_the_time_offset_once() -> None:
    frames = _frames(3, offset_ns=7_000_000)
    np.testing.assert_array_equal(frames.stamp_ns, [0, 40_000_000, 80_000_000])
    np.testing.assert_array_equal(frames.frame_ns, frames.stamp_ns - 7_000_000)
    assert frames.usable.all() and not frames.odd_size


def test_a_frame_of_another_size_is_not_usable() -> None:
    frames = _frames(2)
    small = cv2.imencode(".jpg", np.zeros((10, 20, 3), np.uint8))[1].tobytes()
    odd = scan_colouring.camera_frames(
        "camera", CAM, frames.stamp_ns, [frames.jpegs[0], small], 0, None
    )
    assert odd.usable.tolist() == [True, False] and odd.odd_size == {1: (20, 10)}


def _colour(scan_ns: list[int], frames: list[scan_colouring.CameraFrames], options: views.Options):  # type: ignore[no-untyped-def]
    with ThreadPoolExecutor(2) as pool:
        return scan_colouring.colour_scans(
            _ranges(len(scan_ns)), np.array(scan_ns, dtype=np.int64), BEAMS, frames, None,
            L2V, options, pool=pool,
        )  # fmt: skip


NEAREST = views.Options(view="nearest", motion_compensation=False, balance=False)


def test_each_point_takes_the_colour_of_the_frame_nearest_its_own_time() -> None:
    frames = _frames(4)
    pts, merged = _colour([45_000_000], [frames], NEAREST)  # frames at 40 and 80 ms
    seen = merged.coloured
    assert seen.any() and not seen.all()  # the camera looks one way: not behind it
    near_80 = pts.time_ns > 60_000_000  # the scan lasts 25 ms: its last points pass 60 ms
    assert seen[near_80].any() and seen[~near_80].any()
    np.testing.assert_array_equal(merged.frame[seen], np.where(near_80, 2, 1)[seen])
    want = np.array([[20 * k, 255 - 20 * k, 100] for k in range(4)])
    err = np.abs(merged.rgb[seen].astype(int) - want[merged.frame[seen]]).max()
    assert err <= 3  # JPEG's error on a flat colour
    dt = (pts.time_ns[seen] - frames.frame_ns[merged.frame[seen]]) * 1e-9
    np.testing.assert_allclose(merged.dt_s[seen], dt, atol=1e-6)
    assert (merged.camera[seen] == 0).all() and (merged.camera[~seen] == -1).all()


def test_a_time_offset_moves_which_frame_a_point_takes() -> None:
    plain = _colour([45_000_000], [_frames(4)], NEAREST)[1]
    shifted = _colour([45_000_000], [_frames(4, offset_ns=-30_000_000)], NEAREST)[1]
    # the camera's clock 30 ms behind: its frame stamped 40 ms was taken at 70 ms
    seen = plain.coloured & shifted.coloured
    assert seen.any()
    assert (shifted.frame[seen] <= plain.frame[seen]).all()
    assert (shifted.frame[seen] < plain.frame[seen]).any()


def test_one_scan_at_a_time_colours_as_all_at_once() -> None:
    """The recorder colours each scan as it comes; acq colorize a chunk of them: the
    same points get the same colours from the same frames."""
    frames = [_frames(6)]
    scans = [10_000_000, 60_000_000, 110_000_000, 160_000_000]
    _, together = _colour(scans, frames, NEAREST)
    one = [_colour([t], frames, NEAREST)[1] for t in scans]
    np.testing.assert_array_equal(np.concatenate([m.rgb for m in one]), together.rgb)
    np.testing.assert_array_equal(np.concatenate([m.frame for m in one]), together.frame)


def test_no_camera_leaves_every_point_uncoloured() -> None:
    pts, merged = _colour([0], [], NEAREST)
    assert pts.time_ns.size == 181
    assert not merged.coloured.any() and (merged.camera == -1).all()


def test_a_camera_without_a_frame_near_the_scan_colours_nothing_and_the_others_go_on() -> None:
    """As live, where a camera's frames have not come (stalled, or a loaded host): its
    points stay uncoloured, the other camera's are coloured (the scan was lost before)."""
    none = scan_colouring.camera_frames("none", CAM, np.zeros(0, np.int64), [], 0, None)
    for options in (NEAREST, views.Options(motion_compensation=False)):
        _, merged = _colour([45_000_000], [none], options)
        assert not merged.coloured.any() and np.isnan(merged.dt_s).all()
        _, merged = _colour([45_000_000], [none, _frames(4)], options)
        assert merged.coloured.any() and (merged.camera[merged.coloured] == 1).all()


def test_frames_too_far_in_time_colour_nothing() -> None:
    _, merged = _colour([2_000_000_000], [_frames(3)], NEAREST)  # 1.9 s after the last
    assert not merged.coloured.any()


def test_a_crop_is_the_frame_around_its_points_within_the_frame() -> None:
    from acq.cloud.views import crop_around

    image = np.arange(60 * 80 * 3, dtype=np.uint32).reshape(60, 80, 3).astype(np.uint8)
    uv = np.array([[10.2, 20.7], [30.0, 25.5], [np.nan, 1.0]], np.float32)
    crop = crop_around(image, uv, margin=4)
    assert crop is not None and (crop.x0, crop.y0, crop.size) == (6, 16, (80, 60))
    # to ceil(max) + margin, past the pixel: [6, 35) x [16, 31)
    assert np.array_equal(crop.pixels, image[16:31, 6:35])
    assert not np.shares_memory(crop.pixels, image)  # the frame's buffer is reused
    assert crop.holds(6, 16, 35, 31) and crop.holds(7, 17, 30, 20)
    assert not crop.holds(5, 16, 35, 31) and not crop.holds(6, 15, 35, 31)
    assert not crop.holds(6, 16, 36, 31) and not crop.holds(6, 16, 35, 32)
    edge = crop_around(image, np.array([[1.0, 58.5]], np.float32), margin=4)
    assert edge is not None and (edge.x0, edge.y0) == (0, 54) and edge.pixels.shape[:2] == (6, 6)
    assert crop_around(image, np.full((2, 2), np.nan, np.float32)) is None


def test_points_are_grouped_by_their_frame_in_their_order() -> None:
    # what each frame's task colours: its points, ascending; points without a frame none
    rng = np.random.default_rng(3)
    frame = np.where(rng.random(5000) < 0.3, -1, rng.integers(0, 40, 5000))
    frame[frame == 17] = 18  # a frame no point uses
    got = views._by_frame(frame)
    want: dict[int, list[int]] = {}
    for i, f in enumerate(frame.tolist()):
        if f >= 0:
            want.setdefault(f, []).append(i)
    assert sorted(got) == sorted(want) and 17 not in got
    assert all(got[f].tolist() == want[f] for f in want)
    assert views._by_frame(np.full(3, -1)) == {} and views._by_frame(np.zeros(0, np.int64)) == {}
