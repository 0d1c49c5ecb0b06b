"""Bad and edge inputs of both Gymnasium envs: landmarks at distance 0, reset options, config cross-checks and
messages, render size and rate, step before reset, and the docs that describe them (one test per defect)."""

from __future__ import annotations

import importlib
import inspect
import math
import re
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.error import ResetNeeded

import aibo_gym  # noqa: F401  (registers the ids)
from aibo_gym import robot
from aibo_gym.camera import MIN_SIGHT_MM, Camera
from aibo_gym.config import default_config, make_config
from aibo_gym.envs import AiboBeaconsEnv, WheeledRobotEnv
from aibo_gym.envs.aibo_beacons import AiboBeaconsEnv as _A
from aibo_gym.render import MAX_IMAGE_PX
from aibo_gym.wheeled_config import make_config as make_wheeled_config

A, W = "aibo_gym:AiboBeacons-v0", "aibo_gym:WheeledRobot-v0"
ROOT = Path(__file__).resolve().parents[1]
#: AiboBeacons without any noise: the robot stands still (all velocities 0), every visible beacon is detected
STILL = {"velocities": np.zeros((40, 3)).tolist(), "slip_std": [0.0, 0.0, 0.0], "sigma_height": 0.0,
         "sigma_angle": 0.0, "detect_prob": 1.0, "fov": 2 * math.pi, "range_mm": [0.0, 5000.0]}
#: WheeledRobot with (almost) no noise, every landmark in view reported, velocity = (v, 0, omega)
QUIET = {"motion_cov": np.diag([1e-12, 1e-12, 1e-16]).tolist(), "sigma_range_mm": 0.0, "sigma_bearing": 0.0,
         "detect_prob": 1.0, "fov": 2 * math.pi, "range_mm": [0.0, 8500.0],
         "weights": [[1.0, 0, 0], [0, 0, 1.0], [0, 0, 0], [0, 0, 0], [0, 0, 0]]}


def one_line_error(make, *args, **kwargs) -> str:
    """The message of the ValueError ``make(*args, **kwargs)`` raises (asserted one line)."""
    with pytest.raises(ValueError) as err:
        make(*args, **kwargs)
    msg = str(err.value)
    assert "\n" not in msg
    return msg


# ---------------------------------------------------------------- 1. a landmark at distance 0
def test_aibo_a_beacon_the_robot_stands_on_is_not_seen_and_one_2_mm_away_is():
    env = AiboBeaconsEnv({**STILL, "beacons": [[0.0, 0.0]]})
    env.reset(seed=0)
    obs, _, _, _, info = env.step(0)  # was: ZeroDivisionError in the pinhole 57000 / d
    assert info["sightings"]["count"] == 0 and obs[2] == 0.0
    env = AiboBeaconsEnv({**STILL, "beacons": [[2.0, 0.0]]})
    env.reset(seed=0)
    obs, _, _, _, info = env.step(0)
    assert info["sightings"]["count"] == 1
    assert info["sightings"]["height"][0] == pytest.approx(57000.0 / 2.0) and info["sightings"]["angle"][0] == 0.0
    assert obs[1] == 1000.0 and env.observation_space.contains(obs)  # clipped to the observation bound


def test_aibo_walking_onto_a_beacon_does_not_crash():
    """The tester's run: the fastest forward walk from 140 mm off a beacon, straight over it."""
    env = gym.make(A, config={"beacons": [[2700, 1800]], "range_mm": [0, 5000], "start_pose": [2600, 1700, 0.6],
                              "fov": 6.28})
    env.reset(seed=0)
    fastest = int(np.argmax(env.unwrapped.velocities[:, 0]))
    for _ in range(100):
        obs = env.step(fastest)[0]
        assert env.observation_space.contains(obs)


def test_camera_refuses_a_beacon_closer_than_the_minimum():
    cam = Camera(make_config({**STILL, "beacons": [[0.0, 0.0]]}), 0.0, 0.0)
    assert MIN_SIGHT_MM == 1.0
    assert cam.nearest_visible(0.0, 0.0, 0.0, 0.0) is None
    assert cam.nearest_visible(-0.999, 0.0, 0.0, 0.0) is None
    assert cam.nearest_visible(-1.0, 0.0, 0.0, 0.0) == (0, 1.0, 0.0)


@pytest.mark.parametrize("curve", [{"basis": "inverse", "coef": [0.0, 1000.0]}, {"basis": "power", "coef": [0.0, 1.0]}])
def test_wheeled_a_landmark_the_robot_stands_on_is_not_seen_and_one_2_mm_away_is(curve):
    env = WheeledRobotEnv({**QUIET, "beacons": [[0.0, 0.0], [2.0, 0.0]], "sensor_curve": curve})
    env.reset(seed=0)
    info = env.step(np.zeros(2))[4]
    s = info["sightings"]
    assert s["count"] == 1 and s["beacon"][0] == 1  # not landmark 0 (was: seen, range ~1e9 or a crash)
    expected = 1000.0 / 2.0 if curve["basis"] == "inverse" else 2.0
    assert s["range"][0] == pytest.approx(expected, rel=1e-5) and abs(s["bearing"][0]) < 1e-5


def test_a_range_that_sees_nothing_is_refused():
    for make in (make_config, make_wheeled_config):
        assert "'range_mm'" in one_line_error(make, {"range_mm": [0.0, 0.5]})
        make({"range_mm": [0.0, 1.0]})


# ---------------------------------------------------------------- 2. head_pan schedules are wrapped
def test_a_head_pan_schedule_is_wrapped_to_the_observation_range():
    pans = [10.0, -4.0, math.pi, -math.pi, 0.5]
    wrapped = [10.0 - 4 * math.pi, -4.0 + 2 * math.pi, math.pi, math.pi, 0.5]
    env = AiboBeaconsEnv()
    env.reset(seed=0, options={"head_pan": pans})
    for want in wrapped:
        obs, _, _, _, info = env.step(16)
        assert info["head_pan"] == pytest.approx(want, abs=1e-12) and obs[7] == pytest.approx(want, abs=1e-6)
        assert env.observation_space.contains(obs)


def test_a_wrapped_head_pan_points_the_camera_the_same_way():
    def run(pans):
        env = AiboBeaconsEnv({"detect_prob": 1.0, "fov": 0.5})
        env.reset(seed=3, options={"head_pan": pans})
        return [env.step(16)[4]["sightings"]["beacon"][0] for _ in range(len(pans))]

    pans = np.linspace(-math.pi, math.pi, 60)
    seen = run(pans)
    assert seen == run(pans + 4 * math.pi) == run(pans - 2 * math.pi)
    assert len(set(seen)) >= 3  # the scan sees several beacons: the comparison means something


# ---------------------------------------------------------------- 3. reset options
@pytest.mark.parametrize("options, names", [
    ("x", ["reset options must be None or a dict", "'head_pan'"]),
    ([1], ["reset options must be None or a dict", "list"]),
    ({"foo": 1}, ["unknown reset option 'foo'", "'head_pan'"]),
    ({"images": [True]}, ["unknown reset option 'images'", "'head_pan'"]),
    ({"head_pan": "abc"}, ["reset option 'head_pan'", "got str"]),
    ({"head_pan": []}, ["reset option 'head_pan'", "non-empty"]),
    ({"head_pan": [[0.0]]}, ["reset option 'head_pan'", "1-d"]),
    ({"head_pan": ["1", "2"]}, ["reset option 'head_pan'"]),
    ({"head_pan": [True, False]}, ["reset option 'head_pan'"]),
    ({"head_pan": [0.0, math.nan]}, ["reset option 'head_pan'", "non-finite"]),
    ({"head_pan": [[0.0], [1.0, 2.0]]}, ["reset option 'head_pan'"]),
    ({"head_pan": 0.3}, ["reset option 'head_pan'", "1-d"]),
])
def test_aibo_bad_reset_options_are_one_line_naming_the_option(options, names):
    env = AiboBeaconsEnv()
    msg = one_line_error(env.reset, seed=0, options=options)
    for name in names:
        assert name in msg


@pytest.mark.parametrize("options, names", [
    ("x", ["reset options must be None or a dict", "'images'"]),
    ({"image": [True]}, ["unknown reset option 'image'", "'images'"]),
    ({"head_pan": [0.0]}, ["unknown reset option 'head_pan'", "'images'"]),
    ({"images": []}, ["reset option 'images'", "non-empty"]),
    ({"images": [2, 0]}, ["reset option 'images'", "0 and 1"]),
    ({"images": "abc"}, ["reset option 'images'", "got str"]),
    ({"images": [0.0, 1.0]}, ["reset option 'images'", "float64"]),
])
def test_wheeled_bad_reset_options_are_one_line_naming_the_option(options, names):
    env = WheeledRobotEnv()
    msg = one_line_error(env.reset, seed=0, options=options)
    for name in names:
        assert name in msg


def test_good_reset_options_are_accepted():
    a = AiboBeaconsEnv()
    for options in (None, {}, {"head_pan": None}, {"head_pan": np.array([0.1, 0.2])}, {"head_pan": [1, 2]}):
        a.reset(seed=0, options=options)
        a.step(0)
    w = WheeledRobotEnv()
    for options in (None, {}, {"images": None}, {"images": [1, 0]}, {"images": np.array([True])}):
        w.reset(seed=0, options=options)
        w.step(np.zeros(2))


# ---------------------------------------------------------------- 4. field checks only where they matter
@pytest.mark.parametrize("make", [AiboBeaconsEnv, WheeledRobotEnv])
def test_robot_radius_is_checked_only_for_pymunk_walls(make):
    env = make({"field": [200.0, 200.0], "walls": "clamp"})  # was refused for AiboBeacons, blaming robot_radius
    env.reset(seed=0)
    assert "'robot_radius'" in one_line_error(make, {"field": [200.0, 200.0], "walls": "pymunk"})


@pytest.mark.parametrize("make", [AiboBeaconsEnv, WheeledRobotEnv])
def test_open_walls_accept_a_start_off_the_field_the_others_refuse_it(make):
    env = make({"walls": "open", "start_pose": [3100.0, 0.0, 0.0]})
    np.testing.assert_array_equal(env.reset(seed=0)[1]["pose"], [3100.0, 0.0, 0.0])
    for walls in ("clamp", "pymunk", "none"):
        msg = one_line_error(make, {"walls": walls, "start_pose": [3100.0, 0.0, 0.0]})
        assert "'start_pose'" in msg and "inside the field" in msg


def test_an_open_field_render_shows_a_robot_started_off_the_field():
    env = AiboBeaconsEnv({"walls": "open", "start_pose": [6000.0, 0.0, 0.0]}, render_mode="rgb_array")
    env.reset(seed=0)
    img = env.render()
    robot_px = np.argwhere((img == 20).all(axis=-1))
    assert len(robot_px) > 100 and robot_px[:, 1].min() > 0.8 * img.shape[1]  # at the right end


# ---------------------------------------------------------------- 5 - 7. config messages say what is accepted
def test_the_motion_cov_message_says_what_is_accepted():
    for bad in (None, [[0, 0, 0]] * 3):
        msg = one_line_error(WheeledRobotEnv, {"motion_cov": bad})
        assert "'motion_cov'" in msg and "None or" not in msg and "positive definite" in msg
    msg = one_line_error(AiboBeaconsEnv, {"slip_cov": [[0, 0, 0]] * 3})  # slip_cov does accept None
    assert "'slip_cov'" in msg and "None or" in msg
    AiboBeaconsEnv({"slip_cov": None})


@pytest.mark.parametrize("make", [AiboBeaconsEnv, WheeledRobotEnv])
def test_fov_has_one_message_for_every_bad_value(make):
    expected = {one_line_error(make, {"fov": bad}).split("(expected ", 1)[1] for bad in (-1, 0, 0.0, 7, math.inf)}
    assert expected == {"a number in (0, 6.283] rad (0 < fov <= 2 pi))"}
    make({"fov": 2 * math.pi})
    make({"fov": 1e-3})


@pytest.mark.parametrize("partial", [{"basis": "inverse"}, {"coef": [0.0, 2.0]}, {}])
@pytest.mark.parametrize("make", [AiboBeaconsEnv, WheeledRobotEnv])
def test_a_partial_sensor_curve_is_refused(make, partial):
    msg = one_line_error(make, {"sensor_curve": partial})
    assert "'sensor_curve'" in msg and "both keys" in msg


def test_a_whole_sensor_curve_replaces_the_default():
    env = WheeledRobotEnv({**QUIET, "beacons": [[2800.0, 0.0]], "sensor_curve": {"basis": "inverse", "coef": [0.0, 2.8e6]}})
    env.reset(seed=0)
    assert env.step(np.zeros(2))[4]["sightings"]["range"][0] == pytest.approx(1000.0, rel=1e-6)
    assert "None or" not in one_line_error(WheeledRobotEnv, {"sensor_curve": None})


# ---------------------------------------------------------------- 8 - 9. render size and rate
@pytest.mark.parametrize("config, shape", [
    ({}, (440, 590)),  # the default field at 0.1 px/mm, unchanged
    ({"field": [1e7, 1e7]}, (MAX_IMAGE_PX, MAX_IMAGE_PX)),  # was a 2.73 TiB allocation
    ({"beacons": [[1e5, 0.0]]}, (51, MAX_IMAGE_PX)),  # was 410 x 10320
])
def test_the_rendered_image_stays_within_the_maximum_size(config, shape):
    env = gym.make(A, render_mode="rgb_array", config=config)
    env.reset(seed=0)
    img = env.render()
    assert img.shape == (*shape, 3) and img.dtype == np.uint8
    assert (img == 20).all(axis=-1).sum() > 0  # the robot is still drawn
    env.close()


@pytest.mark.parametrize("make, dt, fps", [(A, 0.1, 10.0), (A, 1 / 30, 30.0), (A, 0.02, 50.0), (W, 0.05, 20.0),
                                           (W, 0.1, 10.0)])
def test_render_fps_is_one_over_dt(make, dt, fps):
    env = gym.make(make, config={"dt": dt})
    assert env.metadata["render_fps"] == pytest.approx(fps)
    assert env.unwrapped.metadata["render_fps"] == pytest.approx(fps)
    assert _A.metadata["render_fps"] == 30 and WheeledRobotEnv.metadata["render_fps"] == 10  # class defaults


# ---------------------------------------------------------------- 10. the docs name what the code has
def test_env_docs_reference_modules_that_exist():
    for obj in (AiboBeaconsEnv, WheeledRobotEnv, robot):
        for name in re.findall(r":mod:`([\w.]+)`", inspect.getdoc(obj)):
            importlib.import_module(name)


def test_environments_md_lists_every_aibo_config_key_and_info_key():
    text = (ROOT / "docs" / "environments.md").read_text()
    section = text.split("## `AiboBeacons-v0`", 1)[1].split("## `WheeledRobot-v0`", 1)[0]
    rows = " ".join(line.split("|")[1] for line in section.splitlines() if line.startswith("| `"))
    assert sorted(k for k in default_config() if f"`{k}`" not in rows) == []
    env = AiboBeaconsEnv()
    listed = section.split("`info` has the same keys", 1)[1].split(".", 1)[0]
    assert sorted(k for k in env.reset(seed=0)[1] if f"`{k}`" not in listed) == []


# ---------------------------------------------------------------- 11. step before reset
@pytest.mark.parametrize("make, action", [(lambda: AiboBeaconsEnv({"walls": "pymunk"}), 0),
                                          (lambda: AiboBeaconsEnv(), 0),
                                          (lambda: WheeledRobotEnv({"walls": "pymunk"}), np.zeros(2)),
                                          (lambda: WheeledRobotEnv(), np.zeros(2))])
def test_step_before_reset_is_a_clear_error(make, action):
    env = make()
    with pytest.raises(ResetNeeded, match=r"call reset\(\) before step\(\)"):
        env.step(action)
    env.reset(seed=0)
    env.step(action)
