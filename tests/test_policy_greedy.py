"""The ``greedy`` (one-step D-optimal) exploration policy: its information bookkeeping and its choices."""

from __future__ import annotations

import numpy as np
import pytest

from aibo.cli import main
from aibo_core import trajectory
from aibo_gym.collect import collect
from aibo_gym.policies import validate_policy
from aibo_gym.policies.greedy import GreedyPolicy, hold_information, logdet_gain

SIGMAS = (2.0, 0.05)  # px, rad
KNOWN_START = np.diag([1e-6, 1e-6, 1e-10])  # the hold's start pose known exactly


def info(t, d=2000.0, bearing=0.0, v=(200.0, 0.0, 0.0), cov=KNOWN_START):
    t = np.atleast_1d(np.asarray(t, dtype=float))
    n = len(t)
    return hold_information(t, np.full(n, d), np.full(n, bearing), np.ones(n), np.asarray(v), cov, *SIGMAS)


def test_a_sighting_at_the_start_of_a_hold_says_nothing_about_its_velocity():
    velocity, sensor = info([0.0])
    np.testing.assert_allclose(velocity, 0.0, atol=1e-12)
    assert np.linalg.eigvalsh(sensor).max() > 0  # but it measures the sensor curve


def test_later_sightings_inform_more_and_an_unknown_start_pose_costs_information():
    early, late = info([1.0])[0], info([4.0])[0]
    assert np.trace(late) > np.trace(early) > 0
    # straight ahead: the height change measures the forward speed; the bearing the sideways one
    assert early[0, 0] > 0 and early[1, 1] > 0
    # two sightings at one time and an unknown start pose: the start pose absorbs them (no velocity)
    broad = np.diag([1e8, 1e8, 10.0])
    same_time = np.trace(info([2.5, 2.5], cov=broad)[0])
    assert same_time < 1e-3 * np.trace(info([2.5, 2.5])[0])
    # two sightings spread over the hold separate the velocity from the start pose
    assert np.trace(info([0.5, 4.5], cov=broad)[0]) > 100 * same_time


def test_logdet_gain_is_the_difference_of_log_determinants():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(3, 3)), rng.normal(size=(3, 2))
    prior, inc = a @ a.T + np.eye(3), b @ b.T
    expected = np.linalg.slogdet(prior + inc)[1] - np.linalg.slogdet(prior)[1]
    assert logdet_gain(prior, inc) == pytest.approx(expected, rel=1e-10)


def test_greedy_is_a_policy_spec_and_deterministic_for_a_seed(tmp_path):
    assert validate_policy("greedy")["params"] == {"hold_s": 5.0, "margin_mm": 300.0, "sensor_weight": 1.0, "path_points": 30.0,
                                                   "criterion": "d"}
    paths = [tmp_path / f"{i}.npz" for i in range(3)]
    for path, seed in zip(paths, (3, 3, 4)):
        assert main(["collect", "--steps", "1500", "--seed", str(seed), "--policy", "greedy", "--out", str(path)]) == 0
    a, b, c = (trajectory.load(p) for p in paths)
    assert a.meta["policy"] == "greedy" and np.array_equal(a.actions, b.actions)
    assert not np.array_equal(a.actions, c.actions)


def _per_command(policy: str, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(holds per command, sightings per command) of a 5-minute log."""
    tr = collect({}, steps=9000, seed=seed, policy=policy)
    holds = np.bincount(tr.actions[::150], minlength=40)
    return holds, np.bincount(tr.actions[tr.sighting_frame], minlength=40)


@pytest.mark.parametrize("seed", [1, 2])
def test_greedy_spreads_the_information_over_the_commands_where_uniform_does_not(seed):
    """D-optimal on a block-diagonal information: an unused command is worth the most, so in 60 holds
    every command is held (uniform repeats some and leaves others out) and the least-observed command
    has more sightings than uniform's."""
    g_holds, g_seen = _per_command("greedy", seed)
    u_holds, u_seen = _per_command("uniform", seed)
    assert np.count_nonzero(g_holds) == 40 > np.count_nonzero(u_holds)
    assert g_seen.min() > u_seen.min()
    assert g_seen.std() / g_seen.mean() < u_seen.std() / u_seen.mean()


def test_greedy_a_criterion_prefers_the_least_known_command():
    pol = GreedyPolicy(None, seed=0, criterion="a")
    pol.velocity_info[3] *= 1e4
    dv = np.diag([1e-3, 1e-3, 10.0])
    assert pol.velocity_gain(0, dv) > 10 * pol.velocity_gain(3, dv)
    xy = GreedyPolicy(None, seed=0, criterion="dxy")  # only (vx, vy) count: a heading-only increment gains nothing
    assert xy.velocity_gain(0, np.diag([0.0, 0.0, 10.0])) == pytest.approx(0.0, abs=1e-9)
    assert xy.velocity_gain(0, dv) > 0.0
    with pytest.raises(ValueError, match="criterion"):
        validate_policy({"greedy": {"criterion": "e"}})
