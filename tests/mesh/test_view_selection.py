"""The view chosen per facet (acq.mesh.view_selection): a facet hidden in its vertices'
frame takes a frame that sees it, the sharpest frame wins, neighbours share one view.

The geometry is placed in front of the real camera of the short simulated drive (its
calibration, frame times and trajectory, read from the MCAP log), so that the frames'
poses, the fisheye projection and the occlusion test are the ones `acq mesh` uses."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from acq.camera import calibfile, projection
from acq.cloud.job import Job
from acq.cloud.views import camera_poses
from acq.geometry.transforms import Rigid
from acq.mesh import texture
from acq.mesh.drive import prepare_mesh
from acq.mesh.view_selection import Occluders, ViewWeights, neighbours, potts, select_views
from acq.sim.drive_log import DriveTruth
from acq.time.sync import on_laser_clock

Drive = tuple[DriveTruth, Path]
SQUARE = np.array([[0, 1, 2], [1, 3, 2]])  # two facets on the corners of a square


@pytest.fixture(scope="module")
def job(short_drive: Drive, tmp_path_factory: pytest.TempPathFactory) -> Job:
    truth, calib = short_drive
    out = tmp_path_factory.mktemp("views") / "m.glb"
    return prepare_mesh(truth.files, calibfile.load(calib), out, texels=8).job


def _pose(job: Job, k: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Camera 0's rotation (3,3), position (3,) m and time (laser clock ns) at frame k."""
    cj = job.cameras[0]
    t = on_laser_clock(cj.frame_new[[k]], cj.time_offset_ns)
    R, p = camera_poses(cj.cam, job.laser_to_vehicle, job.trajectory.pose_at, t)
    return R[0], p[0], int(t[0])


def _square(centre: np.ndarray, facing: np.ndarray, side: float) -> np.ndarray:
    """(4,3) corners of a square of ``side`` m at ``centre``, its normal ``facing``."""
    n = facing / np.linalg.norm(facing)
    u = np.cross(n, [0.0, 0.0, 1.0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    return centre + 0.5 * side * np.array([-u - v, u - v, -u + v, u + v])


def _select(
    job: Job, square: np.ndarray, j: int, t_ns: int, hiding: np.ndarray | None = None,
    weights: ViewWeights | None = None,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The views of the two facets of ``square``, its vertices coloured from frame j
    (two more points, on its corners, from frames j-1 and j+1: frames the colouring
    used), scanned at ``t_ns``; ``hiding`` (N,3) more laser points, scanned then too."""
    xyz = np.concatenate([square, square[:2]])
    frame = np.array([j, j, j, j, j - 1, j + 1])
    camera = np.zeros(6, dtype=np.uint8)
    pts = xyz if hiding is None else np.concatenate([xyz, hiding])
    occ = Occluders(pts, np.full(len(pts), t_ns), np.full(len(pts), 0.02))
    return select_views(job, xyz, np.full(6, t_ns), SQUARE, camera, frame, occ, weights)


def _area_px(job: Job, square: np.ndarray, k: int) -> float:
    """The square's area in camera 0's frame k, px²."""
    R, p, _ = _pose(job, k)
    uv, ok = projection.project((square - p) @ R, job.cameras[0].cam.model, Rigid.identity())
    assert ok.all()
    quad = uv[[0, 1, 3, 2]].astype(np.float64)
    x, y = quad[:, 0], quad[:, 1]
    return float(0.5 * abs(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1))))


def test_a_facet_hidden_in_its_vertices_frame_takes_a_frame_that_sees_it(job: Job) -> None:
    j = job.cameras[0].frame_new.size // 2
    R, p, t_j = _pose(job, j)
    centre = p + 6.0 * R[:, 2]  # on frame j's axis, 6 m out
    square = _square(centre, p - centre, 0.2)
    assert texture.facet_views(np.zeros(4, np.uint8), np.full(4, j), SQUARE)[1].tolist() == [j, j]
    # seen by all three frames: the one nearest in time and on its axis
    cam, fr = _select(job, square, j, t_j)
    assert cam.tolist() == [0, 0] and fr.tolist() == [j, j]
    # a post 1.5 m from the camera on the ray to the square, 0.12 m wide: it hides the
    # square in frame j only (the rig moves 0.22 m a frame; the post shifts 4 times more
    # than the square in the neighbouring frames)
    ray = (centre - p) / np.linalg.norm(centre - p)
    g = np.linspace(-0.06, 0.06, 13)
    post = (
        p
        + 1.5 * ray
        + np.stack(np.meshgrid(g, g), -1).reshape(-1, 2) @ np.stack([R[:, 0], R[:, 1]])
    )
    cam, fr = _select(job, square, j, t_j, hiding=post)
    assert cam.tolist() == [0, 0]
    assert fr[0] == fr[1] and fr[0] in (j - 1, j + 1), fr
    # hidden in every frame (a wall in front): the vertices' own view, the last resort
    wall = (
        p
        + 1.5 * ray
        + np.stack(np.meshgrid(5 * g, 5 * g), -1).reshape(-1, 2) @ np.stack([R[:, 0], R[:, 1]])
    )
    assert _select(job, square, j, t_j, hiding=wall)[1].tolist() == [j, j]


def test_the_frame_that_sees_a_facet_largest_wins(job: Job) -> None:
    j = job.cameras[0].frame_new.size // 2
    R, p, t_j = _pose(job, j)
    _, p_next, _ = _pose(job, j + 1)
    ahead = (p_next - p) / np.linalg.norm(p_next - p)
    # 1.2 m out and 1 m ahead along the track: the rig drives towards it
    centre = p + 1.2 * R[:, 2] + 1.0 * ahead
    square = _square(centre, p - centre, 0.1)
    areas = {k: _area_px(job, square, k) for k in (j - 1, j, j + 1)}
    sharpest = max(areas, key=areas.__getitem__)
    assert sharpest != j and areas[sharpest] > 1.1 * areas[j], areas
    # weighed by resolution alone, the largest; time and angle to the axis weigh for j
    fr = _select(job, square, j, t_j, weights=ViewWeights(per_s=0.0, per_rad2=0.0))[1]
    assert fr.tolist() == [sharpest] * 2
    fr = _select(job, square, j, t_j, weights=ViewWeights(per_s=100.0))[1]
    assert fr.tolist() == [j, j]


def _strip() -> np.ndarray:
    """Eight facets between two profiles of five vertices (four cells)."""
    #  0---1---2---3---4
    #  |  /|  /|  /|  /|
    #  5---6---7---8---9
    upper = np.array([[k, k + 1, k + 5] for k in range(4)])
    lower = np.array([[k + 1, k + 6, k + 5] for k in range(4)])
    return np.concatenate([upper, lower])


def _seams(faces: np.ndarray, label: np.ndarray) -> int:
    a, b = neighbours(faces)
    return int(np.count_nonzero(label[a] != label[b]))


def test_neighbours_prefer_one_view() -> None:
    faces = _strip()
    keys = np.tile([7, 9, -1], (8, 1)).astype(np.int64)
    # each facet's cheaper view alternates (by 0.2); facet 2 can only take view 9
    cost = np.tile([0.0, 0.2, 0.0], (8, 1))
    cost[1::2] = [0.2, 0.0, 0.0]
    cost[2] = [np.inf, 0.0, 0.0]
    alone = potts(keys, cost, faces, smooth=0.0, passes=2)
    assert alone.tolist() == [7, 9, 9, 9, 7, 9, 7, 9]
    together = potts(keys, cost, faces, smooth=0.5, passes=2)
    assert (_seams(faces, alone), _seams(faces, together)) == (3, 0)
    assert together.tolist() == [9] * 8  # facet 2 is held to its only view, the rest join
    # the same whatever the facets' order
    shuffled = np.random.default_rng(1).permutation(8)
    again = potts(keys[shuffled], cost[shuffled], faces[shuffled], smooth=0.5, passes=2)
    assert np.array_equal(again, together[shuffled])
    # a facet no view sees: -1, and no neighbour is drawn to it: each side of it one view
    cost[5] = np.inf
    got = potts(keys, cost, faces, smooth=0.5, passes=2)
    assert got[5] == -1 and (got >= 0).sum() == 7
    assert _seams(faces, got) == 2  # its own two edges
