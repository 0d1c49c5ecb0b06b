"""Stable-Baselines3 subprocess vector envs find the env by its importable id "aibo_gym:AiboBeacons-v0"."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from aibo_gym.envs import AiboBeaconsEnv

ENV_ID = "aibo_gym:AiboBeacons-v0"
README = Path(__file__).resolve().parents[1] / "README.md"


def test_docs_name_the_importable_id_and_the_thread_setting():
    for text in (AiboBeaconsEnv.__doc__, README.read_text()):
        assert f'"{ENV_ID}"' in text
    assert "OMP_NUM_THREADS=1" in README.read_text()


def _rollout(vec, steps: int) -> tuple[np.ndarray, list]:
    vec.seed(7)
    out = [vec.reset()]
    infos = []
    for t in range(steps):
        obs, _, _, infos = vec.step(np.array([t % 40, (3 * t) % 40]))
        out.append(obs)
    vec.close()
    return np.array(out), infos


def test_subproc_vec_env_with_two_workers_steps(monkeypatch):
    pytest.importorskip("stable_baselines3", reason="SB3 is in the 'agents' extra")
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    sub, infos = _rollout(make_vec_env(ENV_ID, n_envs=2, vec_env_cls=SubprocVecEnv), 60)
    dummy, _ = _rollout(make_vec_env(ENV_ID, n_envs=2, vec_env_cls=DummyVecEnv), 60)
    assert sub.shape == (61, 2, 11)
    assert len(infos) == 2 and all(info["sightings"]["beacon"].shape == (1,) for info in infos)
    np.testing.assert_array_equal(sub, dummy)  # the workers run the same seeded envs
    assert np.any(sub[:, :, 6] == 1.0)  # something was seen
