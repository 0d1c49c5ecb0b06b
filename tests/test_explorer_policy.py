"""The learned ``explorer``: its training env (information observation, log-det reward, robots
resampled), the shipped agent as a policy spec, and ``aibo train-explorer`` reproducing an agent."""

from __future__ import annotations

import json

import numpy as np
import pytest

from aibo.cli import main
from aibo_core.actions import N_ACTIONS
from aibo_gym.collect import collect
from aibo_gym.explorer import TRAIN_ROBOT_SEEDS, InfoExplorerEnv
from aibo_gym.policies.explorer import GAIN_SCALE, N_HEAD, N_INFO_FEATURES, SHIPPED_AGENT, UNSAFE, teacher_action


def test_training_env_rewards_the_logdet_increase_and_draws_a_new_robot_each_episode():
    env = InfoExplorerEnv(episode_minutes=1.0)
    obs, info = env.reset(seed=0)
    assert obs.shape == (N_INFO_FEATURES,) and env.observation_space.contains(obs)
    robots = {info["robot_seed"]}
    n, trunc = 0, False
    while not trunc:
        before = env.policy.logdet()
        obs, r, term, trunc, step_info = env.step(teacher_action(obs))
        assert not term and r == pytest.approx(env.reward_scale * (env.policy.logdet() - before))
        assert step_info["logdet_gain"] >= 0.0  # information only grows
        n += 1
    assert n == 12  # 1 minute of 5-s holds
    for _ in range(3):
        robots.add(env.reset()[1]["robot_seed"])
    assert len(robots) == 4 and all(TRAIN_ROBOT_SEEDS[0] <= s < TRAIN_ROBOT_SEEDS[1] for s in robots)
    again = InfoExplorerEnv(episode_minutes=1.0)
    assert again.reset(seed=0)[1]["robot_seed"] == info["robot_seed"]  # seeded


def test_observation_carries_greedys_gains_and_its_choice():
    env = InfoExplorerEnv(episode_minutes=1.0)
    obs, _ = env.reset(seed=4)
    for _ in range(3):
        obs, *_ = env.step(7)
    cand, gain = env.policy.gains()
    predicted = obs[N_HEAD + N_ACTIONS + 1:]
    np.testing.assert_allclose(predicted[cand], np.minimum(gain / GAIN_SCALE, 5.0), rtol=1e-5)
    assert np.all(np.delete(predicted, cand) == UNSAFE)
    assert teacher_action(obs) == cand[np.argmax(gain)]
    assert obs[N_HEAD + 7] > 0  # command 7's information has grown over its prior


def test_the_shipped_agent_is_small():
    assert SHIPPED_AGENT.is_file() and SHIPPED_AGENT.stat().st_size < 1_000_000
    meta = json.loads(SHIPPED_AGENT.with_suffix(".json").read_text())
    assert meta["policy"] == "explorer" and meta["n_features"] == N_INFO_FEATURES


@pytest.mark.slow
def test_explorer_spec_loads_the_shipped_agent_and_is_seeded():
    pytest.importorskip("stable_baselines3", reason="SB3 is in the 'agents' extra")
    tr = collect({"robot_seed": 3}, 900, seed=5, policy="explorer")
    assert tr.meta["policy"] == "explorer"
    assert tr.actions.min() >= 0 and tr.actions.max() < N_ACTIONS
    changes = np.flatnonzero(np.diff(tr.actions)) + 1
    assert np.all(changes % 150 == 0)  # 5-s holds
    again = collect({"robot_seed": 3}, 900, seed=5, policy="explorer")
    np.testing.assert_array_equal(again.actions, tr.actions)


@pytest.mark.slow
def test_train_explorer_cli_reproduces_an_agent_from_its_seed(tmp_path, capsys):
    pytest.importorskip("stable_baselines3", reason="SB3 is in the 'agents' extra")
    import torch
    from stable_baselines3 import PPO

    args = ["train-explorer", "--steps", "16", "--warm-holds", "12", "--episode-minutes", "0.5"]
    paths = [tmp_path / f"{name}.zip" for name in ("a", "b", "c")]
    for path, seed in zip(paths, ("1", "1", "2")):
        assert main(args + ["--seed", seed, "--out", str(path)]) == 0
    assert "--policy explorer" in capsys.readouterr().out
    weights = [PPO.load(p, device="cpu").policy.state_dict() for p in paths]
    assert all(torch.equal(weights[0][k], weights[1][k]) for k in weights[0])
    assert not all(torch.equal(weights[0][k], weights[2][k]) for k in weights[0])
    meta = json.loads(paths[0].with_suffix(".json").read_text())
    assert meta["warm_holds"] == 12 and meta["steps"] == 16 and meta["seed"] == 1
    tr = collect(None, 300, seed=1, policy={"explorer": {"path": str(paths[0]), "deterministic": True}})
    assert tr.meta["policy_params"]["path"] == str(paths[0])
    # an agent for the other observation is refused in one line, each way
    assert main(["train-explorer", "--policy", "explorer", "--algo", "dqn", "--out", str(tmp_path / "d.zip")]) == 2
    assert "PPO" in capsys.readouterr().err
    out = tmp_path / "log.npz"
    assert main(["collect", "--steps", "30", "--policy", f"sb3:{paths[0]}", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "info-v1" in err[0], err
