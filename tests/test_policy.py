"""The random-balanced exploration policy and its EKF localizer."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aibo_gym.collect import collect
from aibo_gym.envs import AiboBeaconsEnv
from aibo_gym.policies import EKFLocalizer, RandomBalancedPolicy


def balance(tr) -> np.ndarray:
    return np.bincount(tr.actions, minlength=40)


@pytest.mark.parametrize("localizer", ["truth", "ekf"])
def test_balanced_over_fifteen_minutes(localizer):
    tr = collect(None, 27000, seed=0, localizer=localizer)
    counts = balance(tr)
    assert np.all(counts > 0)
    assert counts.min() >= 0.5 * counts.mean()
    assert counts.max() <= 1.6 * counts.mean()
    # actions are held for 5 s (150 frames)
    changes = np.flatnonzero(np.diff(tr.actions)) + 1
    assert np.all(np.diff(changes) % 150 == 0)
    # it stays on the field: the clamp walls hold it only rarely
    on_edge = (np.abs(tr.pose[:, 0]) >= 2700 - 1e-9) | (np.abs(tr.pose[:, 1]) >= 1800 - 1e-9)
    assert on_edge.mean() < 0.02


def test_policy_is_seeded():
    a = collect(None, 3000, seed=1).actions
    b = collect(None, 3000, seed=1).actions
    c = collect(None, 3000, seed=2).actions
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_rejects_paths_leaving_the_field():
    pol = RandomBalancedPolicy(None, seed=0)
    pose = np.array([2300.0, 0.0, 0.0])  # 400 mm from the +x edge, facing it
    viol = pol.violation(pose)
    assert viol[16] > 0  # straight ahead for 5 s: 1.8 m, off the field
    assert viol[20] == 0  # straight back: safe
    for _ in range(20):
        assert pol.violation(pose)[pol.choose(pose)] == 0


def test_prefers_least_used():
    pol = RandomBalancedPolicy(None, seed=0)
    pol.counts[:] = 10
    pol.counts[[20, 33]] = 0
    picks = {pol.choose(np.zeros(3)) for _ in range(30)}
    assert picks <= {20, 33} and len(picks) == 2  # ties broken at random


def test_bad_arguments():
    with pytest.raises(ValueError, match="ekf"):
        RandomBalancedPolicy(None, seed=0, localizer="gps")
    with pytest.raises(ValueError, match="random-balanced"):
        collect(None, 10, seed=0, policy="clever")


def test_ekf_tracks_the_true_pose_without_privileged_information():
    env = AiboBeaconsEnv({"noise": "aibo"})
    obs, info = env.reset(seed=5)
    pol = RandomBalancedPolicy(env.config, seed=5, localizer="ekf")
    pol.reset({})  # no pose given: the EKF starts from the configured start pose
    errors = []
    for t in range(6000):
        a = pol.act(obs, {})
        obs, _, _, _, info = env.step(a)
        if t % 30 == 0:
            errors.append(np.hypot(*(pol.pose_estimate[:2] - info["pose"][:2])))
    assert np.median(errors) < 250.0


def test_ekf_correction_pulls_toward_the_measurement():
    ekf = EKFLocalizer([[2000.0, 0.0]], sigma_height=1.0, sigma_angle=0.05)
    ekf.reset([0.0, 0.0, 0.0], [300.0, 300.0, 0.2])
    assert ekf.correct(0, 57000.0 / 1800.0, 0.0)  # beacon looks closer: robot is further +x
    assert ekf.pose[0] > 100.0
    ekf.reset([0.0, 0.0, 0.0], [300.0, 300.0, 0.2])
    ekf.correct(0, 57000.0 / 2000.0, 0.1)  # beacon appears left: robot turned right
    assert ekf.pose[2] < 0.0 or ekf.pose[1] < 0.0
    ekf.predict([10.0, 0.0, math.pi / 2])
    assert np.all(np.isfinite(ekf.cov))
