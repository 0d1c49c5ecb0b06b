"""The hold-level explorer env, a short PPO run, and collecting with the trained agent (sb3:PATH)."""

from __future__ import annotations

import json
import os

import gymnasium as gym
import numpy as np
import pytest

from aibo.cli import main
from aibo_core import trajectory
from aibo_gym.collect import collect
from aibo_gym.config import REWARD_TERMS
from aibo_gym.explorer import HoldWrapper, shield_command
from aibo_gym.policies.onboard import N_FEATURES

ENV_ID = "aibo_gym:AiboBeacons-v0"


def _wrapped(**kw):
    return HoldWrapper(gym.make(ENV_ID, config={"reward": "explore", "max_steps": 600}), **kw)


def test_hold_wrapper_steps_one_hold_and_sums_rewards():
    env = _wrapped(hold_s=1.0, shield=False)
    obs, _ = env.reset(seed=2)
    assert obs.shape == (N_FEATURES,) and env.observation_space.contains(obs)
    inner = env.env.unwrapped
    before = inner.steps
    obs, r, term, trunc, info = env.step(7)
    assert inner.steps - before == 30 and info["command"] == 7
    assert set(info["rewards"]) == set(REWARD_TERMS)
    w = inner.config["reward_weights"]
    assert r == pytest.approx(sum(w[k] * info["rewards"][k] for k in REWARD_TERMS))
    assert env.observation_space.contains(obs)
    n = 1
    while not (term or trunc):
        obs, r, term, trunc, info = env.step(n % 40)
        n += 1
    assert trunc and n == 20  # 600 frames = 20 holds of 30


def test_hold_wrapper_needs_the_exploration_reward():
    with pytest.raises(ValueError, match="reward='explore'"):
        HoldWrapper(gym.make(ENV_ID))


def test_shield_keeps_the_field():
    env = _wrapped(hold_s=5.0)
    env.reset(seed=0)
    tracker = env.env.unwrapped.tracker
    tracker.ekf.m[:] = [2300.0, 0.0, 0.0]  # facing the +x edge, 400 mm from it
    assert shield_command(tracker, 16, 5.0, 300.0) != 16  # straight ahead would leave the field
    assert shield_command(tracker, 20, 5.0, 300.0) == 20  # straight back is safe


@pytest.fixture(scope="module")
def agent(tmp_path_factory):
    pytest.importorskip("stable_baselines3", reason="SB3 is in the 'agents' extra")
    from aibo_gym.train import train_explorer

    out = tmp_path_factory.mktemp("agent") / "ppo.zip"
    train_explorer("ppo", 2048, 0, out, {"max_steps": 600}, hold_s=0.5, n_envs=2, subprocess=False, progress=False,
                   algo_kwargs={"n_steps": 128, "n_epochs": 2})
    return out


def test_training_leaves_no_folder_in_the_temporary_directory(tmp_path, monkeypatch):
    """SB3's default logger made an empty ``SB3-<time>`` folder in the system's temporary directory per run."""
    pytest.importorskip("stable_baselines3", reason="SB3 is in the 'agents' extra")
    import tempfile

    from aibo_gym.train import train_explorer

    system_tmp = tmp_path / "system_tmp"
    system_tmp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(system_tmp))
    train_explorer("ppo", 64, 0, tmp_path / "ppo.zip", {"max_steps": 600}, hold_s=0.5, n_envs=1, subprocess=False,
                   progress=False, algo_kwargs={"n_steps": 32, "n_epochs": 1})
    assert (tmp_path / "ppo.zip").exists()
    assert list(system_tmp.glob("SB3-*")) == []  # (torch may keep its one compile cache there: not per run)


@pytest.mark.slow
def test_short_ppo_run_trains_and_its_rollouts_are_valid_logs(agent, tmp_path):
    meta = json.loads(agent.with_suffix(".json").read_text())
    assert meta["algo"] == "ppo" and meta["hold_s"] == 0.5 and meta["n_features"] == N_FEATURES
    tr = collect({"robot_seed": 3}, 900, seed=5, policy="sb3:" + str(agent))
    assert tr.meta["policy"] == "sb3" and tr.meta["policy_params"]["path"] == str(agent)
    changes = np.flatnonzero(np.diff(tr.actions)) + 1
    assert np.all(np.diff(changes) % 15 == 0)  # held 0.5 s, the agent's hold
    again = collect({"robot_seed": 3}, 900, seed=5, policy="sb3:" + str(agent))
    np.testing.assert_array_equal(again.actions, tr.actions)  # seeded: the same log twice
    trajectory.save(tr, tmp_path / "log.npz")
    back = trajectory.load(tmp_path / "log.npz")  # validated on read
    np.testing.assert_array_equal(back.actions, tr.actions)


@pytest.mark.slow
def test_collect_cli_with_the_agent_and_a_mismatched_one(agent, tmp_path, capsys):
    out = tmp_path / "log.npz"
    assert main(["collect", "--steps", "300", "--seed", "1", "--policy", f"sb3:{agent}", "--out", str(out)]) == 0
    assert trajectory.load(out).n_frames == 300
    from stable_baselines3 import PPO

    other = tmp_path / "cartpole.zip"
    PPO("MlpPolicy", gym.make("CartPole-v1"), n_steps=32, batch_size=32, device="cpu").save(other)
    capsys.readouterr()
    assert main(["collect", "--steps", "60", "--policy", f"sb3:{other}", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cartpole.zip" in err[0] and "do not match" in err[0], err


def test_train_explorer_cli_refuses_a_bad_out(tmp_path, capsys):
    pytest.importorskip("stable_baselines3", reason="SB3 is in the 'agents' extra")
    assert main(["train-explorer", "--steps", "10", "--out", str(tmp_path / "agent.pkl")]) == 2
    assert ".zip" in capsys.readouterr().err


class _FakeAgent:
    """Stands in for an SB3 model: ``save`` writes its bytes (SB3 accepts a file object)."""

    def __init__(self, data: bytes):
        self.data = data

    def save(self, f) -> None:
        f.write(self.data)


def test_an_agent_and_its_description_are_written_all_or_nothing(tmp_path, monkeypatch):
    """A failure while writing the description leaves the old agent AND the old description (the agent was
    replaced first, leaving a new agent beside the old description), and no temp file."""
    import aibo_core.atomic as atomic
    from aibo_gym.policies.sb3 import load_agent
    from aibo_gym.train import _save

    out = tmp_path / "agent.zip"
    _save(_FakeAgent(b"old agent"), out, {"algo": "ppo"})
    old_json = (tmp_path / "agent.json").read_text()
    real_fsync, calls = os.fsync, []

    def full_disk_on_the_second_file(fd):
        calls.append(fd)
        if len(calls) == 2:
            raise OSError(28, "No space left on device")
        real_fsync(fd)

    monkeypatch.setattr(atomic.os, "fsync", full_disk_on_the_second_file)
    with pytest.raises(OSError, match="No space left"):
        _save(_FakeAgent(b"new agent"), out, {"algo": "ppo"})
    monkeypatch.undo()
    assert out.read_bytes() == b"old agent" and (tmp_path / "agent.json").read_text() == old_json
    assert sorted(p.name for p in tmp_path.iterdir()) == ["agent.json", "agent.zip"]
    out.write_bytes(b"another agent")  # a pair that does not belong together is refused by name
    with pytest.raises(ValueError, match="belongs to another agent"):
        load_agent(str(out))
