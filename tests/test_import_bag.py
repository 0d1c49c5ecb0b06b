"""``aibo import bag``: bags written here with rosbags' writers (ROS 1, ROS 2 sqlite3, MCAP) from a 150-s slice of
MRCLAM Dataset 7 give the same log as ``aibo import mrclam`` and the same ``aibo learn`` model; bad bags end in one
line, exit 2 and no output (small synthetic bags)."""

from __future__ import annotations

import json
import re
import shlex
import shutil
import sqlite3
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from aibo.cli import main
from aibo_core import trajectory
from tests._bags import DATA, ELEMENTS_MSG, bag_path, drive, mrclam_slice, write_bag, write_csv, write_landmarks

pytest.importorskip("rosbags", reason="rosbags not installed (pip install 'aibo-gym[bags]')")

TOPICS = ["--commands", "/cmd_vel", "--detections", "/landmarks"]
needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"MRCLAM Dataset 7 not found at {DATA}")


def assert_same_log(a: trajectory.Trajectory, b: trajectory.Trajectory) -> None:
    """Commands, sightings and truth equal to 1e-9 (mm, rad), the sightings' times to 1e-6 s, frames and landmarks exactly."""
    assert (a.n_frames, a.dt, a.control_names, a.sensor_kind) == (b.n_frames, b.dt, b.control_names, b.sensor_kind)
    np.testing.assert_allclose(a.controls, b.controls, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(a.landmarks, b.landmarks)
    np.testing.assert_array_equal(a.sighting_frame, b.sighting_frame)
    np.testing.assert_array_equal(a.sighting_landmark, b.sighting_landmark)
    np.testing.assert_allclose(a.sighting_value, b.sighting_value, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.sighting_time, b.sighting_time, rtol=0, atol=1e-6)  # s: a bag stamps in ns
    assert np.abs(a.sighting_time).max() > 0.01  # the slice's sightings are not on the frame ends
    np.testing.assert_allclose(a.pose[:, :2], b.pose[:, :2], rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.angle(np.exp(1j * (a.pose[:, 2] - b.pose[:, 2]))), 0.0, atol=1e-9)
    assert a.meta["pose_gaps"] == b.meta["pose_gaps"]


@pytest.fixture(scope="module")
def mrclam(tmp_path_factory):
    """(folder with map.csv, the slice's rows, the reference log written by ``aibo import mrclam``)."""
    if not DATA.is_dir():
        pytest.skip(f"MRCLAM Dataset 7 not found at {DATA}")
    folder = tmp_path_factory.mktemp("mrclam_bags")
    rows, seconds = mrclam_slice(robot=1, seconds=150.0)
    write_landmarks(folder / "map.csv", rows)
    ref = folder / "ref.npz"
    assert main(["import", "mrclam", str(DATA), "--robot", "1", "--seconds", repr(seconds), "--out", str(ref)]) == 0
    return folder, rows, ref


@pytest.mark.realdata
@needs_data
@pytest.mark.parametrize("fmt,detections,stamped", [("ros1", "arrays", False), ("db3", "elements", True),
                                                    ("mcap", "markers", True), ("mcap", "arrays", False)])
def test_a_bag_gives_the_mrclam_log(mrclam, tmp_path, fmt, detections, stamped, capsys):
    """Twist / TwistStamped commands, range/bearing arrays, a list of elements or marker poses in the camera's
    optical frame, PoseStamped truth: the same commands, sightings and truth as the MRCLAM importer's."""
    folder, rows, ref = mrclam
    bag = write_bag(tmp_path, rows, fmt, detections, stamped)
    if fmt == "mcap" and detections == "arrays":
        bag = bag.parent  # the ROS 2 folder of the .mcap (the other case reads the bare file)
    out = tmp_path / "bag.npz"
    assert main(["import", "bag", str(bag), *TOPICS, "--truth", "/vicon/pose", "--landmarks", str(folder / "map.csv"),
                 "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    log = trajectory.load(out)
    assert_same_log(log, trajectory.load(ref))
    assert log.meta["command_source"] == "commands" and log.meta["source"]["topics"]["/landmarks"].endswith(
        {"arrays": "RangeBearingArray", "elements": "RangeBearingList", "markers": "MarkerArray"}[detections])
    # sightings of the other robots (subjects 1-5) and of unknown barcodes: counted, named, not fatal
    unknown = log.meta["dropped"]["sightings_unknown_id"]
    assert unknown == int(np.sum(~np.isin(rows.detections[:, 1], rows.landmarks[:, 0]))) > 0
    assert f"sightings unknown id {unknown} (ids not in the map: 2, 3, 4, 5)" in printed  # robot 1 sees the others


@pytest.mark.realdata
@needs_data
def test_a_bag_gives_the_mrclam_model(mrclam, tmp_path):
    """``aibo learn`` on the imported bag (marker poses: values equal to ~1e-12, not bit for bit) fits the model it
    fits on the MRCLAM import: action weights equal to 1e-6 (measured 5e-8 at most: the image angle's deconvolved
    prior and the fit's stop rule carry the inputs' rounding that far; 5e-9 before 2026-11-29), their standard errors
    5e-5 to 0.3."""
    folder, rows, ref = mrclam
    bag = write_bag(tmp_path, rows, "mcap", "markers", stamped=True)
    out = tmp_path / "bag.npz"
    assert main(["import", "bag", str(bag), *TOPICS, "--truth", "/vicon/pose", "--landmarks", str(folder / "map.csv"),
                 "--out", str(out)]) == 0
    models = []
    for log in (ref, out):
        model = tmp_path / f"{log.stem}.json"
        assert main(["learn", str(log), "--out", str(model)]) == 0
        models.append(json.loads(model.read_text()))
    a, b = models
    assert a["action_model"]["control_names"] == b["action_model"]["control_names"]
    np.testing.assert_allclose(a["action_model"]["weights"], b["action_model"]["weights"], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(a["action_model"]["motion_cov"], b["action_model"]["motion_cov"], rtol=1e-6, atol=1e-12)
    for key in ("sigma_range_mm", "sigma_angle"):
        np.testing.assert_allclose(a["sensor_model"].get(key, np.nan), b["sensor_model"].get(key, np.nan), rtol=1e-6)
    assert [e["name"] for e in a["effects"]] == [e["name"] for e in b["effects"]]
    for ea, eb in zip(a["effects"], b["effects"]):
        for key, value in ea["parameters"].items():
            np.testing.assert_allclose(value, eb["parameters"][key], rtol=1e-6, atol=1e-9)


@pytest.mark.realdata
@needs_data
def test_the_csv_layout_gives_the_mrclam_log(mrclam, tmp_path):
    folder, rows, ref = mrclam
    out = tmp_path / "csv.npz"
    assert main(["import", "csv", str(write_csv(tmp_path / "csv", rows)), "--out", str(out)]) == 0
    log = trajectory.load(out)
    assert_same_log(log, trajectory.load(ref))
    assert log.meta["dropped"]["sightings_unknown_id"] > 0


# ---------------------------------------------------------------------------------------- small synthetic bags


def _import(tmp_path, bag, *extra: str) -> tuple[int, str]:
    out = tmp_path / "out.npz"
    code = main(["import", "bag", str(bag), "--landmarks", str(tmp_path / "map.csv"), "--out", str(out), *extra])
    return code, str(out)


def _fails(tmp_path, capsys, bag, *extra: str) -> str:
    """The import fails with one line on stderr, exit 2, no output file; returns the line."""
    code, out = _import(tmp_path, bag, *extra)
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("aibo: error: ") and err.count("\n") == 1, err
    assert not (tmp_path / "out.npz").exists()
    return err


@pytest.fixture
def small(tmp_path):
    rows = drive()
    write_landmarks(tmp_path / "map.csv", rows)
    return rows


def test_odometry_stands_in_for_commands_and_says_so(tmp_path, small):
    bag = write_bag(tmp_path, small, "ros1", odometry=True)
    assert _import(tmp_path, bag, "--odometry", "/odom", "--detections", "/landmarks", "--truth", "/vicon/pose")[0] == 0
    odo = trajectory.load(tmp_path / "out.npz")
    assert odo.meta["command_source"].startswith("odometry")
    (tmp_path / "out.npz").rename(tmp_path / "odo.npz")
    assert _import(tmp_path, bag, *TOPICS, "--truth", "/vicon/pose")[0] == 0
    cmd = trajectory.load(tmp_path / "out.npz")
    assert cmd.meta["command_source"] == "commands"
    np.testing.assert_allclose(odo.controls, cmd.controls, atol=1e-9)
    np.testing.assert_allclose(cmd.controls[:10, 0], small.commands[:10, 1] * 1000.0, atol=1e-9)  # mm/s


def test_an_unknown_landmark_id_is_counted_not_fatal(tmp_path, small, capsys):
    small.detections[3, 1] = 99
    bag = write_bag(tmp_path, small, "mcap")
    assert _import(tmp_path, bag, *TOPICS)[0] == 0
    log = trajectory.load(tmp_path / "out.npz")
    assert log.meta["dropped"]["sightings_unknown_id"] == 1 and log.meta["unknown_ids"] == [99]
    assert log.pose is None and log.n_sightings == len(small.detections) - 1 - log.meta["dropped"]["sightings_outside_span"]
    assert "(ids not in the map: 99)" in capsys.readouterr().out


def _as_from_the_origin(tmp_path, small) -> trajectory.Trajectory:
    """The log just imported (``out.npz``), checked to hold the sightings of ``small`` imported from a bag whose sensor
    sat at the robot's origin (to 1e-6 mm and rad)."""
    moved = trajectory.load(tmp_path / "out.npz")
    (tmp_path / "out.npz").unlink()
    assert _import(tmp_path, write_bag(tmp_path / "origin", small, "db3"), *TOPICS)[0] == 0
    np.testing.assert_allclose(moved.sighting_value, trajectory.load(tmp_path / "out.npz").sighting_value, atol=1e-6)
    return moved


def test_a_sensor_pose_moves_the_sightings_to_the_origin(tmp_path, small):
    """A bag whose camera sat 0.2 m ahead and 0.1 m right, turned 0.25 rad, imported with that --sensor-pose: the
    sightings of the same drive seen from the robot's origin."""
    mounted = drive(sensor=(0.2, -0.1, -0.25))
    bag = write_bag(tmp_path / "mounted", mounted, "db3")
    assert _import(tmp_path, bag, *TOPICS, "--sensor-pose", "0.2,-0.1,-0.25")[0] == 0
    moved = _as_from_the_origin(tmp_path, small)
    assert moved.meta["sensor_pose"] == {"x_m": 0.2, "y_m": -0.1, "yaw_rad": -0.25}


#: base_footprint -> base_link -> a mount 0.2 m ahead -> a camera 0.1 m right of it, turned 0.25 rad clockwise -> its
#: optical frame (z forward, x right: the standard rotation)
MOUNT_TF = [("base_footprint", "base_link", (0.0, 0.0, 0.1), (0.0, 0.0, 0.0, 1.0)),
            ("base_link", "mount", (0.2, 0.0, 0.3), (0.0, 0.0, 0.0, 1.0)),
            ("mount", "camera", (0.0, -0.1, 0.0), (0.0, 0.0, np.sin(-0.125), np.cos(-0.125))),
            ("camera", "camera_optical", (0.0, 0.0, 0.0), (-0.5, 0.5, -0.5, 0.5))]


@pytest.mark.parametrize("fmt,detections,frame,base", [("db3", "arrays", "camera", "base_link"),
                                                       ("mcap", "markers", "camera_optical", "base_link"),
                                                       ("ros1", "elements", "/camera", "base_footprint")])
def test_sensor_pose_tf_places_the_sensor_by_the_static_transforms(tmp_path, small, fmt, detections, frame, base):
    """The drive seen from the camera of ``MOUNT_TF``, its detections in the camera's frame (range and bearing) or
    its optical frame (marker poses), imported with --sensor-pose tf: the sightings from the robot's origin (under
    base_link, or base_footprint, which sits right below it)."""
    mounted = drive(sensor=(0.2, -0.1, -0.25))
    (tmp_path / "mounted").mkdir()
    bag = write_bag(tmp_path / "mounted", mounted, fmt, detections=detections, frame=frame, tf=MOUNT_TF)
    assert _import(tmp_path, bag, *TOPICS, "--sensor-pose", "tf", "--base-frame", base)[0] == 0
    moved = _as_from_the_origin(tmp_path, small)
    assert moved.meta["sensor_pose"] == {"from": "/tf_static", "base_frame": base}


def test_sensor_pose_tf_names_what_it_cannot_find(tmp_path, small, capsys):
    bag = write_bag(tmp_path / "a", small, "db3", frame="lidar", tf=MOUNT_TF)
    err = _fails(tmp_path, capsys, bag, *TOPICS, "--sensor-pose", "tf")
    assert "no static transform joins --base-frame base_link and the detections' frame lidar in /tf_static (frames " \
           "there: base_footprint, base_link, camera, camera_optical, mount)" in err, err
    err = _fails(tmp_path, capsys, write_bag(tmp_path / "b", small, "db3", tf=MOUNT_TF), *TOPICS, "--sensor-pose", "tf")
    assert "a message has no header.frame_id" in err and "--sensor-pose X,Y,YAW" in err, err
    err = _fails(tmp_path, capsys, write_bag(tmp_path / "c", small, "db3", frame="camera"), *TOPICS, "--sensor-pose", "tf")
    assert "/tf_static" in err and "/landmarks" in err, err  # no such topic: the topics present listed
    err = _fails(tmp_path, capsys, bag, *TOPICS, "--base-frame", "base_footprint")
    assert "--base-frame base_footprint: used only with --sensor-pose tf" in err, err


def test_a_truncated_bag_is_one_line(tmp_path, small, capsys):
    for fmt in ("ros1", "mcap"):
        (tmp_path / fmt).mkdir()
        bag = write_bag(tmp_path / fmt, small, fmt)
        data = bag.read_bytes()
        bag.write_bytes(data[: len(data) // 2])
        err = _fails(tmp_path, capsys, bag, *TOPICS)
        assert str(bag) in err and ("truncated" in err or "cannot" in err)


def test_a_ros2_bags_metadata_file_points_to_its_folder(tmp_path, small, capsys):
    bag = write_bag(tmp_path, small, "db3")
    folder = bag if bag.is_dir() else bag.parent
    err = _fails(tmp_path, capsys, folder / "metadata.yaml", *TOPICS)
    assert f"a ROS 2 bag's metadata file: give the bag's folder, {folder}" in err
    assert _import(tmp_path, folder, *TOPICS)[0] == 0


def test_a_missing_topic_lists_the_topics_present(tmp_path, small, capsys):
    bag = write_bag(tmp_path, small, "db3")
    err = _fails(tmp_path, capsys, bag, "--commands", "/cmd_vel_stamped", "--detections", "/landmarks")
    assert "--commands /cmd_vel_stamped: no such topic; the bag has: /cmd_vel (geometry_msgs/msg/Twist), " in err
    assert "/vicon/pose (geometry_msgs/msg/PoseStamped)" in err


def test_a_detection_type_it_cannot_read(tmp_path, small, capsys):
    bag = write_bag(tmp_path, small, "mcap")
    err = _fails(tmp_path, capsys, bag, "--commands", "/cmd_vel", "--detections", "/vicon/pose")
    assert "--detections /vicon/pose: cannot read detections from type geometry_msgs/msg/PoseStamped (fields: header, pose)" in err
    err = _fails(tmp_path, capsys, bag, *TOPICS, "--range-field", "distance")
    assert "expected fields id/ids, distance and bearing/bearings" in err
    err = _fails(tmp_path, capsys, bag, "--commands", "/vicon/pose", "--detections", "/landmarks")
    assert "--commands /vicon/pose: type geometry_msgs/msg/PoseStamped holds no twist" in err


def test_field_names_can_be_given(tmp_path, small):
    """A list of elements read with the default names and with the names given (the same here)."""
    bag = write_bag(tmp_path, small, "ros1", detections="elements")
    assert _import(tmp_path, bag, *TOPICS, "--id-field", "id", "--range-field", "range", "--bearing-field", "bearing")[0] == 0
    log = trajectory.load(tmp_path / "out.npz")
    assert log.n_sightings > 50 and np.isin(log.sighting_value[:, 0], small.detections[:, 2] * 1000.0).all()


def test_a_bag_without_definitions_needs_msg_def(tmp_path, small, capsys):
    """An old ROS 2 .db3 bag embeds no definitions: the standard types come from Humble's, a custom one from
    --msg-def (with its dependencies, as 'ros2 interface show' prints them); the log is the one with definitions."""
    bag = write_bag(tmp_path, small, "db3", detections="elements")
    assert _import(tmp_path, bag, *TOPICS)[0] == 0
    with_defs = trajectory.load(tmp_path / "out.npz")
    (tmp_path / "out.npz").unlink()
    db = next(bag.glob("*.db3"))
    with sqlite3.connect(db) as con:
        con.execute("DELETE FROM message_definitions")
    err = _fails(tmp_path, capsys, bag, *TOPICS)
    assert "--detections /landmarks: the bag holds no definition of its type aibo_test_msgs/msg/RangeBearingList; " \
           "give it with --msg-def FILE.msg" in err
    (tmp_path / "det.msg").write_text(ELEMENTS_MSG)
    assert _import(tmp_path, bag, *TOPICS, "--msg-def", str(tmp_path / "det.msg"))[0] == 0
    np.testing.assert_array_equal(trajectory.load(tmp_path / "out.npz").sighting_value, with_defs.sighting_value)
    (tmp_path / "out.npz").unlink()
    (tmp_path / "bad.msg").write_text("int32[ id\n")
    assert "--msg-def " in _fails(tmp_path, capsys, bag, *TOPICS, "--msg-def", str(tmp_path / "bad.msg"))


def test_timestamps_out_of_order(tmp_path, small, capsys):
    stamps = small.truth[:, 0].copy()
    stamps[[10, 11]] = stamps[[11, 10]]  # recorded in order, stamped out of order
    bag = write_bag(tmp_path, small, "ros1", truth_stamps=stamps)
    err = _fails(tmp_path, capsys, bag, *TOPICS, "--truth", "/vicon/pose")
    assert "--truth /vicon/pose (header.stamp): message 12: time" in err and "must not go back" in err


def test_an_empty_topic(tmp_path, small, capsys):
    bag = write_bag(tmp_path, small, "mcap", empty={"/tag_detections": "geometry_msgs/msg/PoseArray"})
    err = _fails(tmp_path, capsys, bag, "--commands", "/cmd_vel", "--detections", "/tag_detections")
    assert "--detections /tag_detections: the topic has no messages" in err


@pytest.mark.parametrize("edit,expected", [
    (lambda r: r.detections.__setitem__((4, 3), np.nan), "--detections /landmarks: message 2: a bearing of nan (not a "
     "finite number)"),
    (lambda r: r.detections.__setitem__((slice(None), 3), np.degrees(r.detections[:, 3]) + 10.0),
     "--detections /landmarks: message 1: bearing"),  # degrees: "... more than a full turn ...: radians, not degrees"
    (lambda r: r.commands.__setitem__((5, 1), np.nan), "--commands /cmd_vel: message 6: linear.x is nan"),
    (lambda r: r.detections.__setitem__((slice(None), 0), r.detections[:, 0] - 100.0),
     "none of the 90 detections can be used: 90 outside the commands' span"),
])
def test_bad_values_name_their_message(tmp_path, small, capsys, edit, expected):
    edit(small)
    err = _fails(tmp_path, capsys, write_bag(tmp_path, small, "ros1"), *TOPICS)
    assert expected in err, err


def test_landmark_ids_as_messages_hold_them():
    """Integers, integral floats and strings of integers are ids; a fraction or a name is refused, its message named."""
    from aibo_core.rosbag_import import _landmark_ids

    message = np.array([1, 2, 2, 3])
    np.testing.assert_array_equal(_landmark_ids("bag", [np.int32(11), 12.0, "13", np.str_("14")], message),
                                  [11, 12, 13, 14])
    for raw, shown in ((np.float64(11.7), "11.7"), (np.str_("L11"), "'L11'")):
        with pytest.raises(ValueError, match=f"bag: message 2: the id {shown} is not an integer"):
            _landmark_ids("bag", [11, raw, 12, 13], message)


def test_commands_or_odometry_is_required(tmp_path, small, capsys):
    bag = write_bag(tmp_path, small, "ros1")
    assert "--commands" in _fails(tmp_path, capsys, bag, "--detections", "/landmarks")
    assert not bag_path(tmp_path, "ros1").with_suffix(".npz").exists()


# ---------------------------------------------------------------------------------------- the walkthrough

#: docs/real-logs.md's walkthrough, as a user types it (in the folder holding robot.bag and map.csv)
WALKTHROUGH = """\
aibo import bag robot.bag --commands /cmd_vel --detections /landmarks --landmarks map.csv --truth /vicon/pose --out robot.npz
aibo learn robot.npz --out robot.json
aibo diagnose robot.npz --out robot-diagnosis --candidates landmark_bias,actuation_lag --replicas 0
aibo export tum robot.npz --model robot.json --out robot.tum --truth truth.tum
evo_ape tum truth.tum robot.tum
"""


def test_the_docs_walkthrough_is_the_tested_one():
    doc = (Path(__file__).resolve().parents[1] / "docs" / "real-logs.md").read_text()
    assert "```bash\n" + WALKTHROUGH + "```" in doc


@pytest.mark.slow
@pytest.mark.realdata
@needs_data
def test_the_walkthrough_runs(mrclam, tmp_path, monkeypatch, capsys):
    """docs/real-logs.md's commands on a bag of MRCLAM robot 1's first 150 s (ROS 1, Twist, range/bearing arrays):
    a log, a model, a diagnosis, TUM files; evo's APE (when evo_ape is installed) is the RMS learn printed."""
    folder, rows, _ = mrclam
    write_bag(tmp_path, rows, "ros1")
    shutil.copy(folder / "map.csv", tmp_path / "map.csv")
    monkeypatch.chdir(tmp_path)
    start = time.perf_counter()
    for line in WALKTHROUGH.splitlines():
        argv = shlex.split(line)
        if argv[0] == "aibo":
            assert main(argv[1:]) == 0, line
        elif shutil.which(argv[0]):
            evo = subprocess.run(argv, capture_output=True, text=True, check=True).stdout
    print(f"walkthrough: {time.perf_counter() - start:.1f} s")
    learned = capsys.readouterr().out
    rms = float(re.search(r"smoothed pose RMS \(mm\) +[\d.]+ +([\d.]+)", learned).group(1))  # the 'learned' column
    assert (tmp_path / "robot-diagnosis" / "report.html").is_file()
    if shutil.which("evo_ape"):
        assert float(re.search(r"rmse\s+([\d.]+)", evo).group(1)) * 1000.0 == pytest.approx(rms, abs=0.06)


def test_unset_header_stamps_point_to_time_log(tmp_path, small, capsys):
    """Stamps a publisher never set (0) are refused with the fix named; --time log reads the record times."""
    bag = write_bag(tmp_path, small, "mcap", truth_stamps=np.zeros(len(small.truth)))
    err = _fails(tmp_path, capsys, bag, *TOPICS, "--truth", "/vicon/pose")
    assert "--truth /vicon/pose: message 1 has header.stamp 0 (not set by its publisher); use --time log" in err
    assert _import(tmp_path, bag, *TOPICS, "--truth", "/vicon/pose", "--time", "log")[0] == 0
    log = trajectory.load(tmp_path / "out.npz")
    assert log.pose is not None and log.meta["source"]["time"] == "log"
