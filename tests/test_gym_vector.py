"""Vector envs and info-reading wrappers: every info key has one type and shape on every step."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import aibo_gym  # noqa: F401  (registers the id)
from aibo_gym.envs import AiboBeaconsEnv

ROOT = Path(__file__).resolve().parents[1]
MANY = {"effects": {"false_sightings": {"rate": 0.4}}}  # several sightings in some frames
STEPS = 400


def actions(n_envs: int, steps: int) -> np.ndarray:
    return (np.arange(steps)[:, None] * 7 + 13 * np.arange(n_envs)[None, :]) % 40


def single_env_run(config: dict | None, seed: int, acts: np.ndarray) -> dict[str, np.ndarray]:
    """The reference: one env stepped alone (with the vector env's autoreset: next-step mode)."""
    env = AiboBeaconsEnv(config)
    env.reset(seed=seed)
    poses, counts, heights = [], [], []
    for a in acts:
        info = env.step(int(a))[4]
        poses.append(info["pose"])
        counts.append(info["sightings"]["count"])
        heights.append(info["sightings"]["height"])
    return {"pose": np.array(poses), "count": np.array(counts), "height": np.array(heights)}


def vector_run(vec: gym.vector.VectorEnv, seeds: list[int], acts: np.ndarray) -> dict[str, np.ndarray]:
    vec.reset(seed=seeds)
    poses, counts, heights = [], [], []
    for a in acts:
        info = vec.step(a)[4]
        poses.append(info["pose"])
        counts.append(info["sightings"]["count"])
        heights.append(info["sightings"]["height"])
    return {"pose": np.array(poses), "count": np.array(counts), "height": np.array(heights)}


@pytest.mark.parametrize("config", [None, MANY], ids=["plain", "false_sightings"])
def test_sync_vector_env_stacks_infos_and_matches_single_envs(config):
    vec = gym.make_vec("AiboBeacons-v0", num_envs=3, vectorization_mode="sync", config=config)
    acts = actions(3, STEPS)
    got = vector_run(vec, [1, 2, 3], acts)
    vec.close()
    k = AiboBeaconsEnv(config).max_sightings
    assert got["height"].shape == (STEPS, 3, k) and got["count"].shape == (STEPS, 3)
    if config is MANY:
        assert k == 2 and got["count"].max() == 2  # some frame had two sightings
    for i, seed in enumerate([1, 2, 3]):
        ref = single_env_run(config, seed, acts[:, i])
        for key in ("pose", "count", "height"):
            np.testing.assert_array_equal(got[key][:, i], ref[key])


ASYNC_SCRIPT = """
import json, sys
import gymnasium as gym, numpy as np
config = json.loads(sys.argv[1])
vec = gym.make_vec("aibo_gym:AiboBeacons-v0", num_envs=2, vectorization_mode="async", config=config)
vec.reset(seed=[1, 2])
acts = (np.arange({steps})[:, None] * 7 + 13 * np.arange(2)[None, :]) % 40
for a in acts:
    info = vec.step(a)[4]
vec.close()
print(json.dumps({{"pose": info["pose"].tolist(), "count": int(info["sightings"]["count"].sum())}}))
"""


@pytest.mark.parametrize("config", [None, MANY], ids=["plain", "false_sightings"])
def test_async_vector_env_steps_and_closes(config):
    """In a subprocess with a timeout: a crash in a worker used to leave close() hanging."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    script = ASYNC_SCRIPT.format(steps=STEPS)
    done = subprocess.run([sys.executable, "-c", script, json.dumps(config)], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, done.stderr[-2000:]
    out = json.loads(done.stdout.strip().splitlines()[-1])
    acts = actions(2, STEPS)
    for i, seed in enumerate([1, 2]):
        np.testing.assert_array_equal(out["pose"][i], single_env_run(config, seed, acts[:, i])["pose"][-1])


def test_record_episode_statistics_reads_the_infos():
    env = gym.wrappers.RecordEpisodeStatistics(gym.make("AiboBeacons-v0", max_episode_steps=50))
    for episode in range(3):
        env.reset(seed=episode)
        for t in range(50):
            *_, terminated, truncated, info = env.step(t % 40)
        assert truncated and info["episode"]["l"] == 50 and info["episode"]["r"] == 0.0
    assert list(env.length_queue) == [50, 50, 50]


def test_vector_wrappers_read_the_stacked_infos():
    vec = gym.make_vec("AiboBeacons-v0", num_envs=2, vectorization_mode="sync", max_episode_steps=30, config=MANY)
    vec = gym.wrappers.vector.RecordEpisodeStatistics(vec)
    listed = gym.wrappers.vector.DictInfoToList(vec)
    listed.reset(seed=[5, 6])
    ends = 0
    for t in range(95):  # three episodes of 30 steps each, plus the autoreset steps
        _, _, terminated, truncated, infos = listed.step(np.array([t % 40, (t + 3) % 40]))
        assert isinstance(infos, list) and len(infos) == 2
        for info in infos:
            assert info["sightings"]["beacon"].shape == (2,) and info["pose"].shape == (3,)
            if "episode" in info:
                ends += 1
                assert info["episode"]["l"] == 30
    assert ends == 6 and np.all(np.array(vec.length_queue) == 30)
    listed.close()
