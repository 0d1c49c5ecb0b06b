"""WheeledRobot-v0: the Box-action env through the checkers, seeding, its camera, its effects, its config."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest

import aibo_gym  # noqa: F401  (registers the ids)
from aibo_core.features import FEATURE_MAPS, diff_drive, features, linear
from aibo_gym.envs.wheeled_robot import WheeledRobotEnv

#: no noise, every visible landmark reported, velocity = (v, 0, omega) exactly
QUIET = {"motion_cov": np.diag([1e-12, 1e-12, 1e-16]).tolist(), "sigma_range_mm": 0.0, "sigma_bearing": 0.0,
         "detect_prob": 1.0, "weights": [[1.0, 0, 0], [0, 0, 1.0], [0, 0, 0], [0, 0, 0], [0, 0, 0]]}


def run(env: WheeledRobotEnv, commands, seed: int = 0, options=None):
    obs, info = env.reset(seed=seed, options=options)
    out = [(obs, info)]
    for c in commands:
        obs, reward, terminated, truncated, info = env.step(np.asarray(c, float))
        out.append((obs, info))
    return out


CONFIGS = [{}, {"effects": {"false_sightings": {"rate": 0.3}, "actuation_lag": {"lag_s": 0.2}}},
           {"feature_map": "linear", "control_names": ["a", "b", "c"], "control_low": [-1] * 3,
            "control_high": [1] * 3, "weights": np.eye(4, 3).tolist()}]


@pytest.mark.parametrize("config", CONFIGS)
def test_gymnasium_checker_passes(config):
    from gymnasium.utils.env_checker import check_env

    env = gym.make("WheeledRobot-v0", config=config)
    assert env.spec.max_episode_steps == 6000
    assert isinstance(env.action_space, gym.spaces.Box) and env.action_space.shape == (len(env.unwrapped.config["control_names"]),)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # advice only: "use a normalized [-1, 1] action space", "float32 actions"
        check_env(env.unwrapped, skip_render_check=True)


@pytest.mark.parametrize("config", CONFIGS)
def test_sb3_checker_passes(config):
    pytest.importorskip("stable_baselines3", reason="SB3's check_env needs the 'agents' extra")
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # advice only: "use a normalized [-1, 1] action space", "float32 actions"
        sb3_check_env(gym.make("WheeledRobot-v0", config=config).unwrapped, warn=False)


def test_observation_and_info_have_fixed_shapes_and_no_nan():
    env = WheeledRobotEnv({"effects": {"false_sightings": {"rate": 0.3}}})
    assert env.max_sightings == 2 * len(env.landmarks)
    keys = None
    for obs, info in run(env, [[80.0, 0.2]] * 200, seed=3):
        assert obs.shape == env.observation_space.shape and np.all(np.isfinite(obs))
        assert env.observation_space.contains(obs)
        s = info["sightings"]
        shapes = {k: np.shape(v) for k, v in info.items() if k != "sightings"} | {k: np.shape(v) for k, v in s.items()}
        assert keys is None or shapes == keys
        keys = shapes
        assert np.all(s["beacon"][s["count"]:] == -1) and np.all(s["beacon"][:s["count"]] >= 0)
    assert keys["pose"] == (3,) and keys["command"] == (2,) and keys["beacon"] == (env.max_sightings,)


def test_same_seed_same_episode_and_effects_leave_the_base_noise_alone():
    commands = np.column_stack([np.linspace(0, 86, 300), 0.5 * np.sin(np.arange(300) / 20)])

    def trace(config, seed):
        out = []
        for _, i in run(WheeledRobotEnv(config), commands, seed):
            s, n = i["sightings"], i["sightings"]["count"]
            out.append((i["pose"].tobytes(), s["beacon"][:n].tobytes(), s["range"][:n].tobytes(), s["bearing"][:n].tobytes()))
        return out

    assert trace({}, 5) == trace({}, 5)
    assert trace({}, 5) != trace({}, 6)
    # an effect at its neutral value, or one that draws from its own stream only, changes nothing else
    assert trace({"effects": {"floor_drift": {"drift_mm_s": [0.0, 0.0]}, "false_sightings": {"rate": 0.0}}}, 5) == trace({}, 5)


def test_camera_field_of_view_range_limits_and_several_sightings():
    landmarks = [[1000.0, 0.0], [0.0, 1000.0], [9000.0, 0.0], [2000.0, 500.0], [-1500.0, 0.0], [150.0, 0.0]]
    env = WheeledRobotEnv({**QUIET, "beacons": landmarks, "sensor_curve": {"basis": "power", "coef": [10.0, 1.1]}})
    (_, _), (obs, info) = run(env, [[0.0, 0.0]])
    s = info["sightings"]
    # in view: 0 (ahead) and 3 (14 deg left); not: 1 (90 deg), 2 (beyond 8.5 m), 4 (behind), 5 (closer than 300 mm)
    assert s["count"] == 2 and s["beacon"][:2].tolist() == [0, 3]
    d = np.hypot(2000.0, 500.0)
    np.testing.assert_allclose(s["range"][:2], [10 + 1.1 * 1000.0, 10 + 1.1 * d], atol=1e-4)
    np.testing.assert_allclose(s["bearing"][:2], [0.0, np.arctan2(500.0, 2000.0)], atol=1e-7)  # 1e-8 rad motion noise
    np.testing.assert_allclose(obs[:8], [0, 1110, 0, 1, 3, 10 + 1.1 * d, np.arctan2(500.0, 2000.0), 1], rtol=1e-6, atol=1e-6)
    assert obs[8:12].tolist() == [-1, 0, 0, 0]  # unused slot
    # a narrower field of view loses landmark 3 (0.245 rad off the heading)
    env = WheeledRobotEnv({**QUIET, "beacons": landmarks, "fov": 0.4})
    assert run(env, [[0.0, 0.0]])[1][1]["sightings"]["beacon"][:1].tolist() == [0]


def test_detection_probability_and_noise():
    env = WheeledRobotEnv({**QUIET, "beacons": [[2000.0, 0.0]], "detect_prob": 0.6, "sigma_range_mm": 40.0})
    steps = run(env, [[0.0, 0.0]] * 4000, seed=1)[1:]
    ranges = np.array([i["sightings"]["range"][0] for _, i in steps if i["sightings"]["count"]])
    assert len(ranges) / 4000 == pytest.approx(0.6, abs=0.03)
    assert ranges.mean() == pytest.approx(2000.0, abs=3.0) and ranges.std() == pytest.approx(40.0, rel=0.05)


def test_detection_by_distance_interpolates_its_table_and_replaces_the_one_probability():
    """``detect_by_distance`` [[1000, 0.9], [5000, 0.1]]: a landmark at 2 km reported on 0.7 of the frames, at 6 km on
    0.1 (held beyond the last point), whatever ``detect_prob`` says."""
    table = [[1000.0, 0.9], [5000.0, 0.1]]
    env = WheeledRobotEnv({**QUIET, "beacons": [[2000.0, 0.0], [6000.0, 1.0]], "detect_prob": 0.5,
                           "detect_by_distance": table})
    steps = run(env, [[0.0, 0.0]] * 4000, seed=2)[1:]
    seen = np.array([[b in i["sightings"]["beacon"][:i["sightings"]["count"]] for b in (0, 1)] for _, i in steps])
    np.testing.assert_allclose(seen.mean(axis=0), [0.7, 0.1], atol=0.025)


def test_detection_by_angle_multiplies_the_probability_at_the_angle_off_the_heading():
    """``detect_by_angle`` [[0, 1.5], [0.5, 0.5]] times ``detect_prob`` 0.6: a landmark straight ahead reported on 0.9
    of the frames, one 0.4 rad to the right on 0.6 x 0.7 = 0.42."""
    env = WheeledRobotEnv({**QUIET, "beacons": [[2000.0, 0.0], [2000.0 * np.cos(0.4), -2000.0 * np.sin(0.4)]],
                           "detect_prob": 0.6, "detect_by_angle": [[0.0, 1.5], [0.5, 0.5]]})
    steps = run(env, [[0.0, 0.0]] * 4000, seed=3)[1:]
    seen = np.array([[b in i["sightings"]["beacon"][:i["sightings"]["count"]] for b in (0, 1)] for _, i in steps])
    np.testing.assert_allclose(seen.mean(axis=0), [0.9, 0.42], atol=0.025)


def test_image_schedule_and_replayed_image_mask():
    env = WheeledRobotEnv({**QUIET, "image_every": 3})
    images = [i["image"] for _, i in run(env, [[0.0, 0.0]] * 9)[1:]]
    assert images == [False, False, True] * 3
    mask = np.array([True, False, False, True])
    images = [i["image"] for _, i in run(env, [[0.0, 0.0]] * 9, options={"images": mask})[1:]]
    assert images == [True, False, False, True, False, True, False, False, True]  # the schedule after the mask
    counts = [i["sightings"]["count"] for _, i in run(env, [[0.0, 0.0]] * 4, options={"images": mask})[1:]]
    assert counts[1] == counts[2] == 0 and counts[0] == counts[3] > 0


def test_true_motion_is_features_times_weights():
    weights = [[0.9, 0.0, 0.001], [0.0, 0.0, 0.8], [-0.2, 0.0, 0.0], [0.0, 0.0, 0.05], [5.0, 0.0, -0.01]]
    env = WheeledRobotEnv({**QUIET, "feature_map": "unicycle", "weights": weights})
    c = np.array([60.0, -0.3])
    v = diff_drive(c[None])[0] @ np.array(weights)
    _, (_, info) = run(env, [c])
    np.testing.assert_allclose(info["velocity"], v)
    np.testing.assert_allclose(info["pose"], [v[0] * 0.1, 0.0, v[2] * 0.1], atol=1e-6)


def test_actuation_lag_delays_continuous_commands():
    env = WheeledRobotEnv({**QUIET, "effects": {"actuation_lag": {"lag_s": 0.3}}})
    steps = run(env, [[100.0, 0.0]] * 5 + [[0.0, 0.0]] * 2)
    x = [i["pose"][0] for _, i in steps]
    # 3 frames of standing still, then 100 mm/s for 3 frames (the 2 zero commands act only after the lag)
    np.testing.assert_allclose(x, [0, 0, 0, 0, 10, 20, 30, 40], atol=1e-5)


@pytest.mark.parametrize("config, key", [({"speed": 1}, "speed"), ({"weights": [[1, 0, 0]]}, "weights"),
                                         ({"control_low": [0.0]}, "control_low"), ({"fov": 0}, "fov"),
                                         ({"feature_map": "table"}, "feature_map"),
                                         ({"motion_cov": [[1, 0, 0], [0, -1, 0], [0, 0, 1]]}, "motion_cov"),
                                         ({"effects": {"wall_contact": {}}}, "walls"),
                                         ({"detect_by_distance": [[2000, 0.5], [1000, 0.4]]}, "detect_by_distance"),
                                         ({"detect_by_distance": [[1000, 1.5]]}, "detect_by_distance"),
                                         ({"detect_by_angle": [[-0.1, 1.0]]}, "detect_by_angle")])
def test_bad_config_is_one_line_naming_the_key(config, key):
    with pytest.raises(ValueError) as err:
        WheeledRobotEnv(config)
    assert key in str(err.value) and "\n" not in str(err.value)


def test_actions_outside_the_space_are_refused():
    env = WheeledRobotEnv()
    env.reset(seed=0)
    for bad in ([1e4, 0.0], [1.0], [np.nan, 0.0], "go"):
        with pytest.raises(ValueError, match="not in the action space"):
            env.step(bad)


def test_features_in_aibo_core_are_the_learners():
    """The feature maps moved to aibo_core: the learner's action model uses the very same functions."""
    from learners.model import action

    assert action.FEATURE_MAPS is FEATURE_MAPS
    c = np.random.default_rng(0).normal(size=(50, 2)) * [80.0, 0.5]
    v, w = c[:, 0], c[:, 1]
    np.testing.assert_array_equal(features("diff_drive", c), np.column_stack([v, w, v * np.abs(w), np.abs(w), np.ones(50)]))
    np.testing.assert_array_equal(linear(c), np.column_stack([c, np.ones(50)]))
    model = action.ActionModel(np.arange(15.0).reshape(5, 3), np.eye(3), 0.1, "unicycle", ("v_mm_s", "omega_rad_s"))
    np.testing.assert_array_equal(model.features(c), diff_drive(c))
    with pytest.raises(ValueError, match="takes 2 controls"):
        features("diff_drive", np.zeros((3, 3)))


def test_sensing_effects_act_on_the_range_as_the_size_measurement():
    """``Sighting.height`` carries the range (mm): the catalogue's size effects act on it unchanged."""
    landmarks = [[1000.0, 0.0], [2000.0, 500.0]]
    base = {**QUIET, "beacons": landmarks}
    plain = run(WheeledRobotEnv(base), [[0.0, 0.0]])[1][1]["sightings"]["range"][:2]
    scaled = run(WheeledRobotEnv({**base, "effects": {"beacon_height_scale": {"scale": [1.1, 0.95]},
                                                      "height_bias": {"offset_px": 20.0}}}), [[0.0, 0.0]])
    np.testing.assert_allclose(scaled[1][1]["sightings"]["range"][:2], plain * [1.1, 0.95] + 20.0)
    env = WheeledRobotEnv({**base, "effects": {"false_sightings": {"rate": 0.25}}})
    s = [i["sightings"] for _, i in run(env, [[0.0, 0.0]] * 300, seed=2)[1:]]
    fake = np.concatenate([x["range"][:x["count"]][x["spurious"][:x["count"]]] for x in s])
    bearing = np.concatenate([x["bearing"][:x["count"]][x["spurious"][:x["count"]]] for x in s])
    assert 160 < len(fake) < 240  # with probability rate / (1 - rate) = 1/3 per real sighting: about 600 / 3
    assert fake.min() >= 850.0 - 1e-9 and fake.max() <= 8500.0 and np.abs(bearing).max() <= 0.59


def test_a_bad_image_mask_is_refused():
    with pytest.raises(ValueError, match="reset option 'images'"):
        WheeledRobotEnv().reset(seed=0, options={"images": [[True, False]]})
