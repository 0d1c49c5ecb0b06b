"""A sensor away from the robot's origin (``aibo_core.timed_log.SensorPose``, the importers' ``--sensor-pose``): the
conversion and the static transforms (``aibo_core.static_tf``) on cases with known answers, and what it does for a fit
on an independent generator's log (the importers end to end: tests/test_import_csv.py, tests/test_import_bag.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from aibo_core.static_tf import StaticTransforms, rotation
from aibo_core.timed_log import SensorPose, Streams, build, from_sensor
from learners.em.learner import EMLearner
from learners.em.options import EMOptions
from learners.scoring import pose_scores
from tests._diffdrive import diff_drive_log


def test_known_answers():
    ahead, turned = SensorPose(250.0, 0.0, 0.0), SensorPose(0.0, 0.0, np.pi / 2)
    np.testing.assert_allclose(from_sensor(np.array([[1000.0, 0.0]]), ahead), [[1250.0, 0.0]])
    # straight to the sensor's left: (250, 1000) mm from the origin
    np.testing.assert_allclose(from_sensor(np.array([[1000.0, np.pi / 2]]), ahead),
                               [[np.hypot(250.0, 1000.0), np.arctan2(1000.0, 250.0)]])
    # behind the sensor, between it and the origin: straight ahead of the origin at 150 mm
    np.testing.assert_allclose(from_sensor(np.array([[100.0, np.pi]]), ahead), [[150.0, 0.0]], atol=1e-12)
    # a sensor looking left sees ahead what is to the robot's left; its bearing wrapped
    np.testing.assert_allclose(from_sensor(np.array([[500.0, 0.0], [500.0, 3.0]]), turned),
                               [[500.0, np.pi / 2], [500.0, 3.0 + np.pi / 2 - 2 * np.pi]])


def test_a_round_trip_through_any_mount():
    """Landmarks around a robot, measured from a sensor at a random mount, come back to their robot-frame range and
    bearing."""
    rng = np.random.default_rng(0)
    for _ in range(20):
        mount = SensorPose(*rng.uniform(-400.0, 400.0, 2), rng.uniform(-np.pi, np.pi))
        point = rng.uniform(-5000.0, 5000.0, (50, 2))  # robot frame, mm
        c, s = np.cos(mount.yaw_rad), np.sin(mount.yaw_rad)
        rel = point - [mount.x_mm, mount.y_mm]
        in_sensor = np.stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]], axis=1)
        measured = np.stack([np.hypot(*in_sensor.T), np.arctan2(in_sensor[:, 1], in_sensor[:, 0])], axis=1)
        np.testing.assert_allclose(from_sensor(measured, mount),
                                   np.stack([np.hypot(*point.T), np.arctan2(point[:, 1], point[:, 0])], axis=1),
                                   atol=1e-9, rtol=0)


def test_build_checks_the_range_as_measured_then_moves_it():
    streams = Streams(command_t=np.array([0.0, 1.0]), commands=np.zeros((2, 2)), sighting_t=np.array([0.5, 0.5]),
                      sighting_landmark=np.array([0, 0]), sighting_value=np.array([[0.0, 0.0], [1000.0, 0.0]]),
                      landmarks=np.array([[2000.0, 0.0]]))
    log = build(streams, 0.1, {}, "test", SensorPose(250.0, 0.0, 0.0))
    assert log.meta["sensor_pose"] == {"x_m": 0.25, "y_m": 0.0, "yaw_rad": 0.0}
    assert log.meta["dropped"]["sightings_nonpositive_range"] == 1  # a range of 0 from the sensor, not 250 mm moved
    np.testing.assert_allclose(log.sighting_value, [[1250.0, 0.0]])


def test_a_fit_of_the_moved_sightings_tracks_the_robot():
    """An independent generator's 150-s log seen by a camera 250 mm ahead: taken as it is, the smoothed track follows
    the camera (pose RMS 241 mm against the truth, seed 3); moved to the origin, the robot as well as a log whose
    sensor sat there (16.9 against 16.6 mm)."""
    mount = SensorPose(250.0, 0.0, 0.0)
    at_origin = diff_drive_log(150.0, seed=3)
    mounted = diff_drive_log(150.0, seed=3, sensor=(mount.x_mm, mount.y_mm, mount.yaw_rad))
    moved = dataclasses.replace(mounted, sighting_value=from_sensor(mounted.sighting_value, mount))
    pose = {name: pose_scores(EMLearner(EMOptions()).fit([tr]).params, [tr])["pose_rms"]
            for name, tr in (("origin", at_origin), ("as is", mounted), ("moved", moved))}
    assert pose["moved"] < 1.1 * pose["origin"] and pose["as is"] > 150.0, pose


def test_static_transforms_compose_up_and_down_the_tree():
    """base_footprint -> base_link (0.1 m up) -> camera (0.2 m ahead, turned 90 degrees left); base_link -> lidar
    (0.3 m behind): a point 1 m ahead of the camera is 0.2 m ahead and 1 m left of base_link, 0.5 m ahead and 1 m left
    of the lidar (a sibling branch), 0.1 m higher in base_footprint."""
    tf = StaticTransforms()
    tf.add("/base_footprint", "base_link", (0.0, 0.0, 0.1), (0.0, 0.0, 0.0, 1.0))
    tf.add("base_link", "camera", (0.2, 0.0, 0.0), (0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)))
    tf.add("base_link", "/lidar", (-0.3, 0.0, 0.0), (0.0, 0.0, 0.0, 2.0))  # not normalized: normalized first
    ahead = np.array([1.0, 0.0, 0.0])
    for base, expected in (("base_link", [0.2, 1.0, 0.0]), ("lidar", [0.5, 1.0, 0.0]), ("base_footprint", [0.2, 1.0, 0.1])):
        R, t = tf.transform(base, "camera")
        np.testing.assert_allclose(R @ ahead + t, expected, atol=1e-12)
    R, t = tf.transform("camera", "base_link")  # the inverse: base_link's origin is 0.2 m behind the camera
    np.testing.assert_allclose(R @ np.zeros(3) + t, [0.0, 0.2, 0.0], atol=1e-12)
    assert tf.transform("base_link", "odom") is None and tf.frames() == ["base_footprint", "base_link", "camera", "lidar"]
    np.testing.assert_allclose(rotation(-0.5, 0.5, -0.5, 0.5), [[0, 0, 1], [-1, 0, 0], [0, -1, 0]], atol=1e-12)  # optical
    with pytest.raises(ValueError, match="not a rotation"):
        rotation(0.0, 0.0, 0.0, 0.0)
    tf.add("camera", "base_footprint", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    with pytest.raises(ValueError, match="loop"):
        tf.transform("base_link", "camera")
