"""Gymnasium's own generic environment tests, adapted to AiboBeacons-v0 in its three wall modes.

Adapted from the Gymnasium repository at v1.4.0 (commit 95a790e19, "Update to v1.4.0"; the
installed gymnasium is 1.4.0):

* tests/envs/test_envs.py: test_all_env_api (check_env, only expected warnings),
  test_all_env_passive_env_checker, test_env_determinism_rollout (two instances, data_equivalence
  of obs, reward, flags and info, exact), test_pickle_env;
* tests/envs/test_rendering.py: test_render_modes / check_rendered ("rgb_array"; "human" needs a
  display and only warns here);
* tests/envs/test_action_dim_check.py: test_discrete_actions_out_of_bound;
* tests/envs/registration/test_make_vec.py: test_make_vec_num_envs (sync and async);
* tests/wrappers/test_time_aware_observation.py: test_default;
* tests/wrappers/test_record_episode_statistics.py: test_record_episode_statistics;
* tests/wrappers/test_time_limit.py: the truncation at max_episode_steps;
* gymnasium/utils/env_checker.py: check_reset_seed_determinism's ``reset(seed=42); reset()``
  checked across two instances.

Each test is parametrized over ``walls`` in ("clamp", "pymunk", "none"); the env is made with the
importable id "aibo_gym:AiboBeacons-v0" and ``config={"walls": walls}``.
"""

from __future__ import annotations

import pickle
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env, data_equivalence

ENV_ID = "aibo_gym:AiboBeacons-v0"
WALLS = ["clamp", "pymunk", "none"]
HEADLESS = "render_mode='human' needs a display"  # our own warning without a display
SEED = 0
NUM_STEPS = 50


def make(walls: str, **kwargs) -> gym.Env:
    return gym.make(ENV_ID, config={"walls": walls}, **kwargs)


@pytest.mark.parametrize("walls", WALLS)
def test_all_env_api(walls):
    """check_env with the render checks, and no warning but the headless one."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = make(walls, render_mode="rgb_array").unwrapped
        check_env(env)
        env.close()
    unexpected = [str(w.message) for w in caught if HEADLESS not in str(w.message)]
    assert unexpected == []


@pytest.mark.parametrize("walls", WALLS)
def test_all_env_passive_env_checker(walls):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = make(walls)
        env.reset()
        env.step(env.action_space.sample())
        env.close()
    assert [str(w.message) for w in caught] == []


@pytest.mark.parametrize("walls", WALLS)
def test_env_determinism_rollout(walls):
    env_1, env_2 = make(walls, disable_env_checker=True), make(walls, disable_env_checker=True)
    obs_1, info_1 = env_1.reset(seed=SEED)
    obs_2, info_2 = env_2.reset(seed=SEED)
    assert data_equivalence(obs_1, obs_2, exact=True) and data_equivalence(info_1, info_2, exact=True)
    env_1.action_space.seed(SEED)
    for t in range(NUM_STEPS):
        action = env_1.action_space.sample()
        out_1, out_2 = env_1.step(action), env_2.step(action)
        assert data_equivalence(out_1[0], out_2[0], exact=True), f"[{t}] obs"
        assert env_1.observation_space.contains(out_1[0])
        assert out_1[1:4] == out_2[1:4], f"[{t}] reward, terminated, truncated"
        assert data_equivalence(out_1[4], out_2[4], exact=True), f"[{t}] info"
        if out_1[2] or out_1[3]:
            env_1.reset(seed=SEED)
            env_2.reset(seed=SEED)
    env_1.close()
    env_2.close()


@pytest.mark.parametrize("walls", WALLS)
def test_reset_seed_then_unseeded_reset_is_deterministic_across_instances(walls):
    env_1, env_2 = make(walls, disable_env_checker=True), make(walls, disable_env_checker=True)
    config = {"walls": walls, "start_pose": "random", "effects": {"false_sightings": {"rate": 0.3}}}
    env_3, env_4 = gym.make(ENV_ID, config=config), gym.make(ENV_ID, config=config)
    for a, b in ((env_1, env_2), (env_3, env_4)):
        a.reset(seed=42)
        b.reset(seed=42)
        for _ in range(2):
            assert data_equivalence(a.reset(), b.reset(), exact=True)
            for t in range(40):
                assert data_equivalence(a.step(t % 40), b.step(t % 40), exact=True)


@pytest.mark.parametrize("walls", WALLS)
def test_pickle_env(walls):
    env = make(walls).unwrapped
    action = env.action_space.sample()
    env_reset = env.reset(seed=123)
    env_step = env.step(action)
    pickled = pickle.loads(pickle.dumps(env))
    assert data_equivalence(env_reset, pickled.reset(seed=123))
    assert data_equivalence(env_step, pickled.step(action))
    env.close()
    pickled.close()


def check_rendered(frame) -> None:
    assert isinstance(frame, np.ndarray) and frame.ndim == 3 and frame.shape[2] == 3
    assert frame.dtype == np.uint8


@pytest.mark.parametrize("walls", WALLS)
def test_render_modes(walls):
    env = make(walls)
    assert "rgb_array" in env.metadata["render_modes"]
    for mode in env.metadata["render_modes"]:
        if mode != "human":
            new_env = make(walls, render_mode=mode)
            new_env.reset()
            check_rendered(new_env.render())
            new_env.step(new_env.action_space.sample())
            check_rendered(new_env.render())
            new_env.close()
    env.close()


@pytest.mark.parametrize("walls", WALLS)
def test_discrete_actions_out_of_bound(walls):
    env = make(walls).unwrapped
    assert isinstance(env.action_space, gym.spaces.Discrete)
    env.reset()
    with pytest.raises(Exception):  # noqa: B017 (as in Gymnasium)
        env.step(env.action_space.start + env.action_space.n)
    env.close()


@pytest.mark.parametrize("walls", WALLS)
@pytest.mark.parametrize("num_envs", [1, 3])
@pytest.mark.parametrize("vectorization_mode", ["async", "sync"])
def test_make_vec_num_envs(walls, num_envs, vectorization_mode):
    env = gym.make_vec(ENV_ID, num_envs=num_envs, vectorization_mode=vectorization_mode, config={"walls": walls})
    assert env.num_envs == num_envs
    env.reset(seed=SEED)
    obs, *_ = env.step(env.action_space.sample())
    assert obs.shape == (num_envs, 11)
    env.close()


@pytest.mark.parametrize("walls", WALLS)
def test_time_aware_observation_default(walls):
    env = make(walls, disable_env_checker=True)
    wrapped = gym.wrappers.TimeAwareObservation(env)
    assert wrapped.observation_space.shape[0] == env.observation_space.shape[0] + 1
    obs, _ = env.reset()
    wrapped_obs, _ = wrapped.reset()
    assert wrapped.timesteps == 0.0 and wrapped_obs[-1] == 0.0 and wrapped_obs.shape[0] == obs.shape[0] + 1
    for t in (1, 2):
        wrapped_obs, *_ = wrapped.step(env.action_space.sample())
        assert wrapped.timesteps == t and wrapped_obs[-1] == t
    wrapped_obs, _ = wrapped.reset()
    assert wrapped.timesteps == 0.0 and wrapped_obs[-1] == 0.0


@pytest.mark.parametrize("walls", WALLS)
@pytest.mark.parametrize("deque_size", [2, 5])
def test_record_episode_statistics(walls, deque_size):
    env = gym.wrappers.RecordEpisodeStatistics(make(walls, disable_env_checker=True, max_episode_steps=20), deque_size)
    for _ in range(5):
        env.reset()
        assert env.episode_returns == 0.0 and env.episode_lengths == 0
        for _ in range(env.spec.max_episode_steps):
            *_, terminated, truncated, info = env.step(env.action_space.sample())
            if terminated or truncated:
                assert all(item in info["episode"] for item in ["r", "l", "t"])
                break
    assert len(env.return_queue) == deque_size and len(env.length_queue) == deque_size


@pytest.mark.parametrize("walls", WALLS)
def test_time_limit(walls):
    env = make(walls, max_episode_steps=10)
    assert env.spec.max_episode_steps == 10
    env.reset(seed=1)
    flags = [env.step(16)[3] for _ in range(10)]
    assert flags == [False] * 9 + [True]
    assert make(walls).spec.max_episode_steps == 27000
