"""A drive (.mcap) as a layer of `acq view` (acq/view/drive.py, frames.py and their routes):
its path, its frustums, the cloud found beside it or coloured in the background, and the
frame a point was coloured from, checked against the pixel `acq colorize`'s colouring
found for that point; over real HTTP, with hostile logs, calibrations and requests."""

from __future__ import annotations

import io
import json
import shutil
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from PIL import Image

from acq.cli import main
from acq.errors import InputError
from acq.geometry.transforms import Rigid
from acq.sim.drive_log import DriveTruth
from acq.view.drive import FRUSTUM_STEP_M, TRAJECTORY_STEP_M, Drive
from acq.view.frames import FrameError, frame_jpeg, point_frame, point_row
from acq.view.points_payload import split_payload
from acq.view.server import DEFAULT_MAX_POINTS, ViewServer
from tests.log_rewrite import mcap_copy
from tests.view.drive_files import ColouredDrive, coloured_drive

SPEED_MS = 20 / 3.6  # the simulated drive's speed


@pytest.fixture(scope="module")
def drive(
    short_drive: tuple[DriveTruth, Path], tmp_path_factory: pytest.TempPathFactory
) -> ColouredDrive:
    return coloured_drive(short_drive, tmp_path_factory.mktemp("drive"))


def _get(url: str) -> tuple[int, bytes, str]:
    try:
        with urllib.request.urlopen(url, timeout=30) as r:
            return r.status, r.read(), r.headers["Content-Type"]
    except urllib.error.HTTPError as e:
        return e.code, e.read(), e.headers["Content-Type"]


def _json(url: str) -> tuple[int, Any]:
    status, body, kind = _get(url)
    assert kind == "application/json", (status, body)
    return status, json.loads(body)


def test_the_path_follows_the_drive_and_the_frustums_are_the_frames_poses(
    drive: ColouredDrive, tmp_path: Path
) -> None:
    d = Drive([drive.log], cache=tmp_path)
    assert d.calib_path == drive.calib  # calib.yaml beside the log, by default
    path = d.path()
    steps = np.linalg.norm(np.diff(path, axis=0), axis=1)
    assert (steps[:-1] >= TRAJECTORY_STEP_M).all() and steps.max() < 2 * TRAJECTORY_STEP_M
    # the odometry's path: the simulated speed over the trajectory's span
    assert d.trajectory is not None
    span_s = (d.trajectory.t_ns[-1] - d.trajectory.t_ns[0]) * 1e-9
    assert steps.sum() == pytest.approx(SPEED_MS * span_s, rel=0.01)
    (cam,) = d.frustums()
    assert cam["camera"] == "camera" and cam["size"] == [780, 582]
    p, R = np.array(cam["p"]), np.array(cam["R"]).reshape(-1, 3, 3)
    apart = np.linalg.norm(np.diff(p, axis=0), axis=1)
    assert (apart[:-1] >= FRUSTUM_STEP_M).all() and (apart < FRUSTUM_STEP_M + 0.3).all()
    assert len(p) >= 11 / FRUSTUM_STEP_M
    # each: the vehicle's pose at the frame's re-timed time o laser_to_vehicle o camera_to_laser
    assert d.job is not None
    cj = d.job.cameras[0]
    t = (cj.frame_new + cj.time_offset_ns)[cam["frames"]]
    for k, tk in enumerate(t):
        Rv, pv = d.trajectory.pose_at(np.array([tk]))
        m = (
            Rigid(Rv[0], pv[0]).matrix()
            @ d.job.laser_to_vehicle.matrix()
            @ cj.cam.camera_to_laser.matrix()
        )
        np.testing.assert_allclose(R[k], m[:3, :3], atol=1e-9)
        np.testing.assert_allclose(p[k], m[:3, 3], atol=1e-9)
    assert d.cloud_state()["status"] == "found" and d.cloud() == drive.cloud


def test_a_points_frame_and_pixel_are_those_the_colouring_used(drive: ColouredDrive) -> None:
    assert drive.cloud is not None
    d = Drive([drive.folder])
    rows = np.flatnonzero(drive.frame >= 0)
    assert rows.size > 1000
    for row in rows[:: rows.size // 25]:
        answer = point_frame(d, point_row(drive.cloud, int(row)))
        assert answer["camera"] == "camera" and answer["frame"] == drive.frame[row]
        np.testing.assert_allclose(answer["pixel"], drive.uv[row], atol=1e-3)
        assert answer["in_image"] and 0 <= answer["t_s"] <= 2.5
    none = int(np.flatnonzero(drive.frame < 0)[0])
    answer = point_frame(d, point_row(drive.cloud, none))
    assert (
        answer["camera"] is None and answer["message"] == f"point {none} was coloured by no camera"
    )
    jpeg = frame_jpeg(d, "camera", int(drive.frame[rows[0]]))
    assert Image.open(io.BytesIO(jpeg)).size == (780, 582)
    with pytest.raises(FrameError, match="camera camera has no frame 48"):
        frame_jpeg(d, "camera", 48)
    with pytest.raises(FrameError, match="no point 10000000"):
        point_row(drive.cloud, 10_000_000)


def test_the_routes_over_http(drive: ColouredDrive) -> None:
    assert drive.cloud is not None
    with ViewServer([drive.log]) as server:
        url = server.url
        status, layers = _json(f"{url}api/layers")
        assert [(x["kind"], x["url"]) for x in layers] == [("drive", "/data/0/drive.json")]
        status, data = _json(f"{url}data/0/drive.json")
        assert data["cloud"]["status"] == "found" and data["cloud"]["url"] == "/data/0/cloud.bin"
        assert data["cloud"]["attributes"] == "/data/0/cloud-attributes.bin"
        assert data["frame"] == "odometry" and len(data["frustums"][0]["p"]) >= 5
        # the cloud packed for the page as a cloud layer is (every point: under the limit),
        # its positions and colours first, its other attributes apart
        split = split_payload(drive.cloud, DEFAULT_MAX_POINTS)
        assert _get(f"{url}data/0/cloud.bin")[1] == split.points
        assert _get(f"{url}data/0/cloud-attributes.bin")[1] == split.attributes
        row = int(np.flatnonzero(drive.frame >= 0)[500])
        status, answer = _json(f"{url}api/frame?layer=0&point={row}")
        assert status == 200 and answer["frame"] == drive.frame[row]
        np.testing.assert_allclose(answer["pixel"], drive.uv[row], atol=1e-3)
        assert answer["url"] == f"/data/0/frame/camera/{answer['frame']}.jpg"
        status, jpeg, kind = _get(url + answer["url"][1:])
        assert status == 200 and kind == "image/jpeg"
        assert Image.open(io.BytesIO(jpeg)).size == (780, 582)
        # hostile requests: a clear JSON error, never a traceback
        for query, code, said in [
            ("layer=0&point=99999999", 404, "no point 99999999"),
            ("layer=0&point=-1", 404, "no point -1"),
            ("layer=7&point=1", 404, "no layer 7"),
            ("layer=0", 400, "expected /api/frame?layer=K&point=I"),
            ("layer=x&point=1", 400, "integers"),
        ]:
            status, answer = _json(f"{url}api/frame?{query}")
            assert (status, said in answer["error"]) == (code, True), answer
        for bad in ("frame/camera/48.jpg", "frame/camera/-1.jpg", "frame/nobody/1.jpg",
                    "frame/camera/x.jpg", "frame/camera", "nothing.json"):  # fmt: skip
            assert _get(f"{url}data/0/{bad}")[0] == 404, bad


def test_a_cloud_layer_s_points_map_to_its_rows_by_the_subset_rule(
    drive: ColouredDrive, tmp_path: Path
) -> None:
    """A LAS cloud given with its log, served as a subset: the page's point I is the
    file's row I * count // shown."""
    from acq.camera import calibfile
    from acq.cloud import colorize

    las = tmp_path / "cloud.las"
    colorize.run([drive.log], calibfile.load(drive.calib), las)
    with ViewServer([las, drive.log], max_points=10_000) as server:
        layers = server.listing()
        assert layers[0]["log"] == 1 and layers[0]["shown"] == 10_000
        count = layers[0]["count"]
        assert count == len(drive.frame)
        for point in (0, 4321, 9999):
            row = point * count // 10_000
            status, answer = _json(f"{server.url}api/frame?layer=0&point={point}")
            assert status == 200 and answer["row"] == row
            if drive.frame[row] < 0:
                assert answer["camera"] is None
            else:
                assert answer["frame"] == drive.frame[row]
                # LAS keeps the point to its scale (mm): a few hundredths of a pixel here
                np.testing.assert_allclose(answer["pixel"], drive.uv[row], atol=0.1)
        status, answer = _json(f"{server.url}api/frame?layer=0&point=10000")
        assert status == 404 and "no point 10000 (the page has 10000)" in answer["error"]
        # the drive's own cloud (cloud.ply beside its log) answers for itself
        status, answer = _json(f"{server.url}api/frame?layer=1&point=0")
        assert status == 200 and answer["log"] == 1 and answer["row"] == 0
        las.unlink()  # a cloud gone since the start: said, naming it
        status, answer = _json(f"{server.url}api/frame?layer=0&point=1")
        assert status == 409 and "cloud.las" in answer["error"], answer


def test_a_drive_without_a_cloud_beside_it_is_coloured_into_the_cache(
    short_drive: tuple[DriveTruth, Path], drive: ColouredDrive, tmp_path: Path
) -> None:
    bare = coloured_drive(short_drive, tmp_path / "bare", cloud_name=None)
    cache = tmp_path / "cache"
    with ViewServer([bare.folder], cache=cache) as server:
        d = server.drives[0]
        d.wait(60)
        status, data = _json(f"{server.url}data/0/drive.json")
        assert (
            status == 200
            and data["cloud"]["status"] == "ready"
            and data["cloud"]["progress"] == 1.0
        )
        served = _get(f"{server.url}data/0/cloud.bin")[1]
    (cached,) = cache.iterdir()
    assert served == split_payload(cached, DEFAULT_MAX_POINTS).points
    made = cached.read_bytes()
    assert drive.cloud is not None
    # the same cloud `acq colorize` makes (its header's room and comments aside)
    body = made[made.index(b"end_header\n") :]
    assert body == drive.cloud.read_bytes()[drive.cloud.read_bytes().index(b"end_header\n") :]
    assert sorted(p.name for p in bare.folder.iterdir()) == sorted([bare.log.name, "calib.yaml"])
    again = Drive([bare.log], cache=cache)
    assert again.cloud_state()["status"] == "ready" and again.cloud() == cached


def test_a_cloud_that_cannot_be_made_is_said_in_the_page_s_data(
    short_drive: tuple[DriveTruth, Path], tmp_path: Path
) -> None:
    bare = coloured_drive(short_drive, tmp_path / "bare", cloud_name=None)
    cache = tmp_path / "cache"
    cache.write_text("a file where the cache folder would be")
    with ViewServer([bare.log], cache=cache) as server:
        server.drives[0].wait(60)
        status, data = _json(f"{server.url}data/0/drive.json")
    assert status == 200 and data["cloud"]["status"] == "failed"
    assert data["cloud"]["message"].startswith("colouring the cloud: ")
    assert str(cache) in data["cloud"]["message"]
    assert "url" not in data["cloud"]


def test_no_calibration_shows_the_path_alone_and_says_why(
    drive: ColouredDrive, tmp_path: Path
) -> None:
    alone = Path(shutil.copy2(drive.log, tmp_path))
    d = Drive([alone], cache=tmp_path / "cache")
    assert len(d.path()) > 10 and d.frustums() == []
    assert d.cloud_state() == {
        "status": "none", "file": None, "progress": 0.0,
        "message": "no cloud beside the log, and no calibration to colour one",
    }  # fmt: skip
    assert any(
        n.startswith("no calibration (calib.yaml beside the log, or --calib)") for n in d.notes
    )


def test_a_log_without_frames_or_odometry_shows_what_it_can(
    drive: ColouredDrive, tmp_path: Path
) -> None:
    no_frames = tmp_path / "no_frames.mcap"
    mcap_copy(drive.log, no_frames, keep=lambda topic: "image" not in topic)
    d = Drive([no_frames], drive.calib, cache=tmp_path / "cache")
    assert "the log has no camera frames: no camera frustums" in d.notes
    assert d.frustums() == [] and len(d.path()) > 10
    assert d.cloud_state()["message"] == (
        "no cloud beside the log, and no camera frames in the log to colour one"
    )
    no_odometry = tmp_path / "no_odometry.mcap"
    mcap_copy(drive.log, no_odometry, keep=lambda topic: "odometry" not in topic)
    d = Drive([no_odometry], drive.calib, cache=tmp_path / "cache")
    assert d.trajectory is None and len(d.path()) == 0 and d.frustums() == []
    assert any(n.startswith("no trajectory (the log has no CAN odometry") for n in d.notes)
    assert d.data()["frame"] is None


def test_hostile_logs_and_calibrations_are_refused_in_one_line(
    drive: ColouredDrive, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    def refused(argv: list[str], *named: str) -> None:
        assert main(["view", *argv]) == 2
        err = capsys.readouterr().err.splitlines()
        assert err[-1].startswith("acq view: ") and all(n in err[-1] for n in named), err

    cut = tmp_path / "cut.mcap"
    cut.write_bytes(drive.log.read_bytes()[:300])
    refused([str(cut)], str(cut), "no laser scanner")
    renamed = yaml.safe_load(drive.calib.read_text())
    renamed["cameras"]["front"] = renamed["cameras"].pop("camera")
    renamed["cameras"]["back"] = renamed["cameras"]["front"]
    other = tmp_path / "other.yaml"
    other.write_text(yaml.safe_dump(renamed))
    refused([str(drive.log), "--calib", str(other)], "do not match", str(other))
    refused([str(drive.log), "--calib", str(tmp_path / "gone.yaml")], "gone.yaml")
    assert drive.cloud is not None
    refused([str(drive.cloud), "--calib", str(drive.calib)], "--calib", "no .mcap log")
    with pytest.raises(InputError, match=r"gone\.mcap: no such file"):
        ViewServer([tmp_path / "gone.mcap"])
    # nothing written beside the inputs
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cut.mcap", "other.yaml"]


def test_a_folder_s_cloud_is_its_drive_s_cloud_sent_once(drive: ColouredDrive) -> None:
    """The folder `acq colorize` wrote into: its cloud a layer of its own, which the drive
    names as its cloud (not sent twice) and whose points' frames come from the drive."""
    with ViewServer([drive.folder]) as server:
        layers = server.listing()
        assert [(x["name"], x["kind"], x["log"]) for x in layers] == [
            ("cloud.ply", "cloud", 1), (drive.log.name, "drive", None),
        ]  # fmt: skip
        status, data = _json(f"{server.url}data/1/drive.json")
        assert data["cloud"]["layer"] == 0 and "url" not in data["cloud"]
        row = int(np.flatnonzero(drive.frame >= 0)[100])
        status, answer = _json(f"{server.url}api/frame?layer=0&point={row}")
        assert status == 200 and answer["log"] == 1 and answer["frame"] == drive.frame[row]
        assert answer["url"] == f"/data/1/frame/camera/{answer['frame']}.jpg"
