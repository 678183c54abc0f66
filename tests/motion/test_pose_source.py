"""The choice of trajectory from a log's vehicle data (trajectory_from_vehicle), on
messages encoded and decoded as the recorder logs them, and the PoseSource interface."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from acq.geometry.rotations import matrices_from_euler
from acq.geometry.transforms import Rigid
from acq.motion import Chosen, PoseSource, from_odometry, trajectory_from_vehicle
from acq.sim.vehicle_messages import ORIGIN, T0, drive, speeds, tf_poses, vehicle_log


def _placed(source: PoseSource, t_ns: np.ndarray) -> np.ndarray:
    """What colouring does with a pose source: vehicle-frame points into its world."""
    return source.transform(t_ns, np.tile([1.0, 0.0, 0.0], (t_ns.size, 1)))


def test_a_trajectory_is_a_pose_source() -> None:
    traj = from_odometry(T0 + np.arange(3) * 10**8, [1.0] * 3, [0.0] * 3)
    assert isinstance(traj, PoseSource)
    assert traj.world.name == traj.frame == "odometry"
    t = T0 + np.array([0, 5 * 10**7, 3 * 10**8])
    assert traj.covers(t).tolist() == [True, True, False]
    np.testing.assert_allclose(_placed(traj, t[:2]), [[1.0, 0, 0], [1.05, 0, 0]])


def test_odometry_alone_is_dead_reckoned_from_start() -> None:
    vehicle = vehicle_log(drive(10.0, odometry_hz=50.0))
    chosen = trajectory_from_vehicle(vehicle)
    assert chosen.description == "CAN odometry (500 samples, dead reckoning)"
    assert chosen.notes == ("no /gnss/fix messages",)
    odo = vehicle.odometry
    expected = from_odometry(odo.t_ns, odo.speed, odo.yaw_rate)
    assert chosen.trajectory is not None
    np.testing.assert_allclose(chosen.trajectory.translation, expected.translation)
    start = Rigid(matrices_from_euler(0.0, 0.0, 1.0)[0], np.array([3.0, 4.0, 0.0]))
    moved = trajectory_from_vehicle(vehicle, start=start).trajectory
    assert moved is not None
    np.testing.assert_allclose(moved.translation, start.apply(expected.translation), atol=1e-9)
    with pytest.raises(dataclasses.FrozenInstanceError):
        chosen.description = "x"  # type: ignore[misc]


def test_odometry_with_fixes_is_fused_in_enu_at_the_first_fix_or_the_given_origin() -> None:
    vehicle = vehicle_log(drive(20.0, odometry_hz=50.0, gnss_hz=5.0))
    chosen = trajectory_from_vehicle(vehicle)
    assert chosen.description.startswith("CAN odometry (1000 samples) fused with 100 GNSS fixes")
    traj = chosen.trajectory
    assert traj is not None and traj.frame == "enu"
    np.testing.assert_allclose(traj.origin, ORIGIN, atol=1e-5)  # the first fix, 2 cm noise
    # the truth starts at the origin heading east: the fused track follows it
    t = T0 + np.arange(0, 19 * 10**9, 10**9)
    fine = np.arange(0.0, 20.0, 0.005)
    truth = from_odometry(T0 + np.round(fine * 1e9).astype(np.int64), *speeds(fine))
    d = np.linalg.norm(traj.pose_at(t)[1][:, :2] - truth.pose_at(t)[1][:, :2], axis=1)
    assert d.max() < 0.1, d
    elsewhere = (ORIGIN[0] + 0.001, ORIGIN[1], ORIGIN[2])  # 111 m further north
    moved = trajectory_from_vehicle(vehicle, enu_origin=elsewhere).trajectory
    assert moved is not None and moved.origin == pytest.approx(elsewhere)
    np.testing.assert_allclose(moved.translation[:, 1], traj.translation[:, 1] - 111.2, atol=0.1)


def test_fixes_alone_give_gnss_alone_and_a_parked_car_none() -> None:
    chosen = trajectory_from_vehicle(vehicle_log(drive(10.0, odometry_hz=0.0, gnss_hz=5.0)))
    assert chosen.description.startswith("GNSS alone (50 fixes; heading from the track")
    assert chosen.trajectory is not None and chosen.trajectory.frame == "enu"
    parked = drive(2.0, odometry_hz=0.0, gnss_hz=5.0)
    for _, msg in parked:  # every fix at the first one's place
        msg.latitude, msg.longitude = parked[0][1].latitude, parked[0][1].longitude
    none = trajectory_from_vehicle(vehicle_log(parked))
    assert none.trajectory is None and none.description == ""
    assert none.notes[-1].endswith(": no trajectory") and "never moves" in none.notes[-1]


def test_no_vehicle_data_and_fixes_out_of_range_are_said_in_notes() -> None:
    assert trajectory_from_vehicle(vehicle_log([])) == Chosen(
        None, "", ("no /vehicle/odometry messages", "no /gnss/fix messages")
    )
    messages = drive(4.0, odometry_hz=20.0, gnss_hz=5.0)
    fixes = [msg for topic, msg in messages if topic == "/gnss/fix"]
    for msg in fixes[:3]:
        msg.latitude = 91.0
    chosen = trajectory_from_vehicle(vehicle_log(messages))
    assert "fused with 17 GNSS fixes" in chosen.description
    assert any(n.startswith("GNSS: 3 of 20 fixes out of range") for n in chosen.notes)


def test_a_crs_projects_the_fixes() -> None:
    vehicle = vehicle_log(drive(10.0, odometry_hz=20.0, gnss_hz=5.0))
    traj = trajectory_from_vehicle(vehicle, "EPSG:25832").trajectory
    assert traj is not None and traj.frame == "EPSG:25832" and traj.origin == (0.0, 0.0, 0.0)
    assert 5.3e6 < traj.translation[0, 1] < 5.4e6  # UTM northing at 48.1° N


def test_a_bags_tf_poses_are_taken_as_they_are_without_odometry() -> None:
    messages = tf_poses(3.0)
    chosen = trajectory_from_vehicle(vehicle_log(messages))
    assert chosen.kind == "poses" and chosen.trajectory is not None
    assert chosen.description == "the log's odom -> base_link poses (60, /tf)"
    fine = np.arange(0.0, 3.0, 0.005)
    truth = from_odometry(T0 + np.round(fine * 1e9).astype(np.int64), *speeds(fine))
    t = chosen.trajectory.t_ns
    np.testing.assert_allclose(chosen.trajectory.translation, truth.pose_at(t)[1], atol=1e-3)
    with_odometry = trajectory_from_vehicle(vehicle_log(messages + drive(3.0, 50.0)))
    assert with_odometry.kind == "odometry"  # the CAN bus when there is one
