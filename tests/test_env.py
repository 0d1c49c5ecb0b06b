"""AiboBeacons-v0: checkers, registration, seeding, action table, action model, config errors."""

from __future__ import annotations

import json
import math
import time
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env

import aibo_gym
from aibo_core.actions import A_TURN, B_DIRECTION, action_index, attempted_velocities
from aibo_core.trajectory import save
from aibo_gym.collect import collect
from aibo_gym.config import default_config, make_config
from aibo_gym.envs import AiboBeaconsEnv
from aibo_gym.policies import RandomBalancedPolicy
from aibo_gym.robot import nominal_velocities, true_velocities
from tests._logs import frame_view


# ---------------------------------------------------------------- checkers and registration
@pytest.mark.parametrize("walls", ["clamp", "pymunk", "none"])
def test_gymnasium_env_checker(walls):
    env = gym.make("AiboBeacons-v0", config={"walls": walls}, render_mode="rgb_array")
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="render_mode='human' needs a display")
        gym_check_env(env.unwrapped)


@pytest.mark.parametrize("walls", ["clamp", "pymunk"])
def test_sb3_env_checker(walls):
    pytest.importorskip("stable_baselines3", reason="SB3's check_env needs the 'agents' extra")
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    sb3_check_env(AiboBeaconsEnv({"walls": walls}), warn=True)


def test_make_with_module_prefix_and_make_vec():
    env = gym.make("aibo_gym:AiboBeacons-v0")
    obs, info = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    assert set(info) == {"pose", "sightings", "head_pan", "action_velocity", "wall_contact", "rewards"}
    vec = gym.make_vec("AiboBeacons-v0", num_envs=2, vectorization_mode="sync")
    obs, _ = vec.reset(seed=[1, 2])
    assert obs.shape == (2, 11)
    obs, rew, term, trunc, _ = vec.step(np.array([3, 17]))
    assert obs.shape == (2, 11) and rew.tolist() == [0.0, 0.0]
    vec.close()


def test_step_outputs_and_observation_layout():
    env = gym.make("AiboBeacons-v0", config={"detect_prob": 1.0})
    obs, info = env.reset(seed=3)
    assert np.all(obs == 0) and info["sightings"]["count"] == 0
    seen = 0
    for t in range(300):
        obs, reward, term, trunc, info = env.step(t % 40)
        assert reward == 0.0 and not term and not trunc
        assert obs.dtype == np.float32 and env.observation_space.contains(obs)
        assert obs[7] == pytest.approx(info["head_pan"], abs=1e-6)
        np.testing.assert_allclose(obs[8:11], attempted_velocities()[t % 40], atol=1e-6)
        assert -math.pi < info["pose"][2] <= math.pi
        s = info["sightings"]
        assert s["count"] in (0, 1) and s["beacon"].shape == (1,) and not s["spurious"][0]
        if s["count"] == 0:
            assert obs[:7].tolist() == [0.0] * 7 and s["beacon"][0] == -1
        else:
            seen += 1
            onehot = np.zeros(4)
            onehot[s["beacon"][0]] = 1
            np.testing.assert_array_equal(obs[:4], onehot)
            assert obs[4] == pytest.approx(s["height"][0], rel=1e-6)
            assert obs[5] == pytest.approx(s["angle"][0], abs=1e-6)
            assert obs[6] == 1.0
    assert seen > 50


def test_truncation_at_max_steps():
    env = AiboBeaconsEnv({"max_steps": 5})
    env.reset(seed=0)
    flags = [env.step(0)[3] for _ in range(5)]
    assert flags == [False, False, False, False, True]


def test_spec_has_the_time_limit_and_time_aware_observation_works():
    env = gym.make("AiboBeacons-v0")
    assert env.spec.max_episode_steps == default_config()["max_steps"] == 27000
    timed = gym.wrappers.TimeAwareObservation(gym.make("AiboBeacons-v0"))
    obs, _ = timed.reset(seed=0)
    assert obs.shape == (12,) and obs[-1] == 0.0
    for t in range(1, 4):
        obs = timed.step(16)[0]
        assert obs[-1] == t and timed.observation_space.contains(obs)
    # make's max_episode_steps sets the spec and truncates; a shorter config max_steps truncates first
    short = gym.make("AiboBeacons-v0", max_episode_steps=3)
    short.reset(seed=0)
    assert short.spec.max_episode_steps == 3
    assert [short.step(0)[3] for _ in range(3)] == [False, False, True]
    shorter = gym.make("AiboBeacons-v0", config={"max_steps": 2}, max_episode_steps=3)
    shorter.reset(seed=0)
    assert [shorter.step(0)[3] for _ in range(2)] == [False, True]


@pytest.mark.parametrize("action", [1.5, 1.0, -1, 40, np.float64(2.0), "3", np.array([3]), None])
def test_actions_outside_the_action_space_are_rejected(action):
    env = gym.make("AiboBeacons-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action .*Discrete\(40\)"):
        env.step(action)


@pytest.mark.parametrize("action", [3, np.int64(3), np.int32(3), np.uint8(3), np.array(3)])
def test_integer_actions_are_accepted(action):
    env = AiboBeaconsEnv()
    env.reset(seed=0)
    reference = AiboBeaconsEnv()
    reference.reset(seed=0)
    np.testing.assert_array_equal(env.step(action)[0], reference.step(3)[0])


def test_random_start_pose_is_seeded_and_on_field():
    env = AiboBeaconsEnv({"start_pose": "random"})
    p1 = env.reset(seed=11)[1]["pose"]
    p2 = env.reset(seed=11)[1]["pose"]
    p3 = env.reset(seed=12)[1]["pose"]
    np.testing.assert_array_equal(p1, p2)
    assert not np.array_equal(p1, p3)
    assert abs(p1[0]) <= 2200 and abs(p1[1]) <= 1300


def test_start_pose_config():
    env = AiboBeaconsEnv({"start_pose": [100.0, -200.0, 1.0]})
    np.testing.assert_array_equal(env.reset(seed=0)[1]["pose"], [100.0, -200.0, 1.0])


# ---------------------------------------------------------------- seeding
def _log_bytes(tmp_path, name, seed, **kw):
    tr = collect(kw.get("config"), 600, seed=seed)
    path = tmp_path / name
    save(tr, path)
    return path.read_bytes()


def test_same_seed_same_log_bytes(tmp_path, monkeypatch):
    a = _log_bytes(tmp_path, "a.npz", 5)
    # saved at another wall-clock time: the zip timestamps are fixed, so the bytes still match
    monkeypatch.setattr(time, "time", lambda: 1_700_000_000.0)
    monkeypatch.setattr(time, "localtime", lambda *_: (2030, 5, 5, 5, 5, 5, 0, 0, 0))
    b = _log_bytes(tmp_path, "b.npz", 5)
    c = _log_bytes(tmp_path, "c.npz", 6)
    assert a == b
    assert a != c


def test_same_seed_same_observations_through_gym_make():
    def run(seed):
        env = gym.make("AiboBeacons-v0", config={"walls": "pymunk", "big_slip_prob": 0.1})
        obs, info = env.reset(seed=seed)
        out = [obs]
        poses = [info["pose"]]
        for t in range(400):
            obs, _, _, _, info = env.step((7 * t) % 40)
            out.append(obs)
            poses.append(info["pose"])
        return np.array(out), np.array(poses)

    o1, p1 = run(9)
    o2, p2 = run(9)
    o3, p3 = run(10)
    np.testing.assert_array_equal(o1, o2)
    np.testing.assert_array_equal(p1, p2)
    assert not np.array_equal(p1, p3)


def test_collect_equals_stepping_through_gym_make():
    config = {"walls": "pymunk"}
    tr = collect(config, 900, seed=4)
    env = gym.make("AiboBeacons-v0", config=config)
    obs, info = env.reset(seed=4)
    pol = RandomBalancedPolicy(env.unwrapped.config, seed=4)
    pol.reset(info)
    actions, poses, heights = [], [info["pose"]], []
    for _ in range(900):
        a = pol.act(obs, info)
        obs, _, _, _, info = env.step(a)
        actions.append(a)
        poses.append(info["pose"])
        s = info["sightings"]
        heights.append(s["height"][0] if s["count"] else np.nan)
    np.testing.assert_array_equal(tr.actions, actions)
    np.testing.assert_array_equal(tr.pose, np.array(poses))
    np.testing.assert_array_equal(frame_view(tr)[0][:, 0], np.array(heights))


# ---------------------------------------------------------------- actions and action model
def test_action_table():
    att = attempted_velocities()
    assert att.shape == (40, 3)
    np.testing.assert_allclose(np.linalg.norm(att, axis=1), 1.0)
    for i, a in enumerate(A_TURN):
        for j, b in enumerate(B_DIRECTION):
            k = action_index(i, j)
            assert k == 8 * i + j
            r = math.sqrt(1 - a * a)
            np.testing.assert_allclose(att[k], [r * math.cos(b), r * math.sin(b), a], atol=1e-12)
    np.testing.assert_allclose(att[16], [1, 0, 0], atol=1e-12)  # a = 0, b = 0: straight ahead
    np.testing.assert_allclose(att[18], [0, 1, 0], atol=1e-12)  # b = pi/2: left
    assert att[0, 2] == -0.5 and att[39, 2] == 0.5
    with pytest.raises(ValueError):
        action_index(5, 0)


def test_true_action_model():
    v = true_velocities()
    assert v.shape == (40, 3)
    np.testing.assert_allclose(v.max(axis=0) - v.min(axis=0), [710.0, 840.0, math.pi])
    np.testing.assert_array_equal(v, true_velocities({"robot_seed": 0, "noise": "aibo", "walls": "pymunk"}))
    assert not np.allclose(v, true_velocities({"robot_seed": 1}))
    nominal = nominal_velocities()
    np.testing.assert_allclose(np.abs(nominal).max(axis=0), [355.0, 420.0, math.pi / 2])
    rel = np.abs(v - nominal) / np.array([710.0, 840.0, math.pi])
    assert 0.005 < rel.mean() < 0.2  # distorted, but recognizably the attempted actions
    turning = nominal[:, 2] != 0
    assert np.all(np.sign(v[turning, 2]) == np.sign(nominal[turning, 2]))  # turns keep their direction
    custom = np.arange(120, dtype=float).reshape(40, 3)
    np.testing.assert_array_equal(true_velocities({"velocities": custom.tolist()}), custom)
    env = AiboBeaconsEnv({"velocities": custom})
    env.reset(seed=0)
    np.testing.assert_array_equal(env.step(7)[4]["action_velocity"], custom[7])


def test_motion_follows_velocity_without_noise():
    v = np.zeros((40, 3))
    v[5] = [300.0, -90.0, 0.6]
    env = AiboBeaconsEnv({"velocities": v, "slip_std": [0, 0, 0], "start_pose": [0, 0, 0.3]})
    env.reset(seed=0)
    pose = env.step(5)[4]["pose"]
    dt = 1 / 30
    c, s = math.cos(0.3), math.sin(0.3)
    np.testing.assert_allclose(pose, [(c * 300 + s * 90) * dt, (s * 300 - c * 90) * dt, 0.3 + 0.6 * dt])


# ---------------------------------------------------------------- config errors
def test_default_config_is_complete_and_json():
    cfg = make_config(None)
    assert set(cfg) == set(default_config())
    json.dumps(cfg)


@pytest.mark.parametrize(
    "config, names",
    [
        ({"wals": "clamp"}, ["'wals'", "walls"]),
        ({"noise": "loud"}, ["'noise'", "paper-sim", "aibo"]),
        ({"walls": "bouncy"}, ["'walls'", "clamp", "pymunk", "none"]),
        ({"start_pose": "anywhere"}, ["'start_pose'", "random"]),
        ({"start_pose": [9000, 0, 0]}, ["'start_pose'"]),
        ({"dt": -1}, ["'dt'"]),
        ({"velocities": [[0, 0, 0]] * 39}, ["'velocities'", "40 x 3"]),
        ({"detect_prob": 1.5}, ["'detect_prob'"]),
        ({"reward": "curiosity"}, ["'reward'", "none", "explore"]),
        ({"reward_weights": {"speed": 1}}, ["'reward_weights'", "speed", "coverage"]),
        ({"reward_weights": {"wall": "x"}}, ["'reward_weights'", "wall"]),
        ({"range_mm": [4000, 1000]}, ["'range_mm'"]),
        ({"max_steps": 0}, ["'max_steps'"]),
    ],
)
def test_config_errors_name_key_and_choices(config, names):
    with pytest.raises(ValueError) as err:
        gym.make("AiboBeacons-v0", config=config)
    for name in names:
        assert name in str(err.value)


def test_nested_config_dicts_merge():
    cfg = make_config({"effects": {"height_bias": {"offset_px": 1.0}}})
    assert cfg["effects"] == {"height_bias": {"offset_px": 1.0}}
    assert make_config({"sigma_height": 2.0})["noise"] == "paper-sim"


# ---------------------------------------------------------------- rendering
def test_render_rgb_array():
    env = gym.make("AiboBeacons-v0", render_mode="rgb_array")
    env.reset(seed=0)
    for _ in range(30):
        env.step(16)
    img = env.render()
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 5  # field, beacons, robot, camera zone
    env.close()


def test_render_human_headless_warns(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    env = AiboBeaconsEnv(render_mode="human")
    with pytest.warns(UserWarning, match="needs a display"):
        env.reset(seed=0)
    env.close()


def test_generator_and_truth_schema():
    tr = collect({"noise": "aibo"}, 50, seed=2)
    assert tr.meta["generator"] == f"aibo_gym {aibo_gym.__version__} AiboBeacons-v0"
    assert tr.meta["seed"] == 2 and tr.meta["policy"] == "random-balanced" and tr.meta["localizer"] == "truth"
    assert tr.meta["config"] == make_config({"noise": "aibo"})
    truth = tr.truth
    assert set(truth) == {"velocities", "motion_noise_std", "big_slip_prob", "sensor", "sigma_height",
                          "sigma_angle", "effects", "start_pose"}
    np.testing.assert_array_equal(truth["velocities"], true_velocities())
    assert truth["sensor"] == {"model": "pinhole", "height_px_mm": 57000.0}
    assert (truth["sigma_height"], truth["sigma_angle"]) == (1.59, 0.0267)
    assert truth["motion_noise_std"] == [3.0, 3.0, 0.02]
    assert tr.pose.shape == (51, 3)
    json.dumps(tr.meta)
