"""The named exploration reward terms (info["rewards"]): each recomputed here from its documented
definition, independently of OnboardTracker."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aibo_gym.config import DEFAULT_REWARD_WEIGHTS, REWARD_TERMS, make_config
from aibo_gym.envs import AiboBeaconsEnv
from aibo_gym.policies import EKFLocalizer
from aibo_gym.policies.onboard import N_CELLS, OnboardTracker
from aibo_gym.robot import nominal_velocities


def _run(config, actions):
    env = AiboBeaconsEnv(config)
    obs, info = env.reset(seed=3)
    out = [(0, info, 0.0)]
    for a in actions:
        obs, r, term, trunc, info = env.step(int(a))
        out.append((a, info, r))
    return env, out


def test_none_gives_zero_terms_with_fixed_keys():
    _, steps = _run(None, [5] * 50)
    for _, info, r in steps:
        assert r == 0.0 and info["rewards"] == dict.fromkeys(REWARD_TERMS, 0.0)


def test_each_term_as_documented():
    rng = np.random.default_rng(0)
    actions = np.repeat(rng.integers(0, 40, 30), 60)  # 30 commands held 2 s
    weights = {"balance": 0.5, "coverage": 2.0, "sightings": 0.01, "wall": 0.1, "info_gain": 0.03}
    env, steps = _run({"reward": "explore", "reward_weights": weights}, actions)
    cfg = env.config
    # an independent onboard EKF and bookkeeping
    ekf = EKFLocalizer(cfg["beacons"], 1.0, 0.5, cfg["slip_std"])
    ekf.reset(cfg["start_pose"], [50.0, 50.0, 0.05])
    disp = nominal_velocities(cfg["nominal_max"]) * cfg["dt"]
    counts = np.zeros(40)
    cells: set = set()
    h_prev = 0.0
    rmin, rmax = cfg["range_mm"]
    for a, info, r in steps[1:]:
        terms = info["rewards"]
        assert set(terms) == set(REWARD_TERMS) and all(type(v) is float for v in terms.values())
        assert r == pytest.approx(sum(weights[k] * terms[k] for k in REWARD_TERMS))
        counts[a] += 1
        p = counts[counts > 0] / counts.sum()
        h = float(-(p * np.log(p)).sum() / math.log(40))
        assert terms["balance"] == pytest.approx(h - h_prev, abs=1e-12)
        h_prev = h
        s = info["sightings"]
        assert terms["sightings"] == s["count"]
        ekf.predict(disp[a])
        new, gain = 0, 0.0
        for j in range(s["count"]):
            d = 57000.0 / s["height"][j]
            cell = (a, min(max(int((d - rmin) / (rmax - rmin) * 6), 0), 5),
                    min(int((s["angle"][j] + math.pi) / (2 * math.pi) * 8), 7))
            new += cell not in cells
            cells.add(cell)
            before = np.linalg.slogdet(ekf.cov)[1]
            if ekf.correct(int(s["beacon"][j]), float(s["height"][j]), float(s["angle"][j])):
                gain += 0.5 * (before - np.linalg.slogdet(ekf.cov)[1])
        assert terms["coverage"] == pytest.approx(new / N_CELLS)
        assert terms["info_gain"] == pytest.approx(gain, rel=1e-9, abs=1e-12)
        edge = min(2700 - abs(ekf.mean[0]), 1800 - abs(ekf.mean[1]))
        assert terms["wall"] == pytest.approx(-min(max(1 - edge / 300.0, 0.0), 1.0))
    total = {k: sum(i["rewards"][k] for _, i, _ in steps) for k in REWARD_TERMS}
    assert total["balance"] == pytest.approx(h_prev)  # the episode sum is the final entropy
    assert total["coverage"] == pytest.approx(len(cells) / N_CELLS)
    assert total["info_gain"] > 0 and total["sightings"] > 0 and total["wall"] <= 0


def test_terms_use_no_true_pose():
    """Two robots with different true velocities but the same sightings give the same terms."""
    cfg = make_config({"reward": "explore"})
    a, b = OnboardTracker(cfg), OnboardTracker(cfg)
    a.reset(), b.reset()
    for t in range(100):
        s = [(0, 30.0, 0.4)] if t % 3 == 0 else []
        assert a.step(t % 40, s) == b.step(t % 40, s)


def test_wall_term_from_the_estimate():
    tr = OnboardTracker(make_config(None))
    tr.reset()
    tr.ekf.m[:] = [2700 - 150 - 16.0, 0.0, 0.0]  # the step moves it ~ +11.8 mm: ~ 138 mm from the edge
    terms = tr.step(16, [])
    edge = 2700 - tr.ekf.mean[0]
    assert terms["wall"] == pytest.approx(-(1 - edge / 300.0))


def test_default_weights_and_validation():
    cfg = make_config({"reward": "explore", "reward_weights": {"sightings": 0.5}})
    assert cfg["reward_weights"] == {**DEFAULT_REWARD_WEIGHTS, "sightings": 0.5}
    with pytest.raises(ValueError, match="unknown reward term 'speed'"):
        make_config({"reward_weights": {"speed": 1.0}})
    with pytest.raises(ValueError, match="reward_weights"):
        make_config({"reward_weights": {"wall": float("nan")}})
