"""Policies as specs {name, params}: uniform, random-balanced, informed, sb3:PATH."""

from __future__ import annotations

import numpy as np
import pytest

from aibo.cli import main
from aibo_core import trajectory
from aibo_gym.collect import collect
from aibo_gym.policies import POLICIES, InformedPolicy, make_policy, policy_label, validate_policy


def test_registry_and_specs():
    assert list(POLICIES)[:4] == ["random-balanced", "uniform", "informed", "sb3"]
    assert validate_policy("uniform") == {"name": "uniform", "params": {"hold_s": 5.0, "margin_mm": 300.0}}
    assert validate_policy({"informed": {"hold_s": 3}})["params"]["hold_s"] == 3.0
    assert validate_policy({"name": "informed", "params": {"coverage_weight": 0}})["params"]["coverage_weight"] == 0.0
    assert validate_policy("sb3:agents/a.zip") == {"name": "sb3", "params": {
        "path": "agents/a.zip", "hold_s": None, "margin_mm": 300.0, "deterministic": False, "shield": True}}
    assert policy_label("sb3:x/y/agent.zip") == "sb3:agent.zip"


@pytest.mark.parametrize("spec, words", [
    ("clever", ["'clever'", "valid choices", "informed"]),
    ({"informed": {"speed": 1}}, ["'informed'", "unknown parameter 'speed'", "prior_sightings"]),
    ({"uniform": {"hold_s": "x"}}, ["'uniform'", "'hold_s'", "finite number"]),
    ({"random-balanced": {"localizer": "gps"}}, ["'localizer'", "'ekf'"]),
    ({"uniform": {"hold_s": 0}}, ["hold_s", "positive"]),
])
def test_bad_specs_are_one_line(spec, words):
    with pytest.raises(ValueError) as err:
        make_policy(spec, None, 0)
    msg = str(err.value)
    assert "\n" not in msg and all(w in msg for w in words), msg


@pytest.mark.parametrize("policy", ["uniform", "informed", "greedy", "explorer"])
def test_onboard_policies_need_no_true_pose_and_keep_on_field(policy):
    from aibo_gym.envs import AiboBeaconsEnv

    if policy == "explorer":
        pytest.importorskip("stable_baselines3", reason="the explorer's agent needs the 'agents' extra")

    env = AiboBeaconsEnv({"robot_seed": 5})
    pol = make_policy(policy, env.config, 1)
    obs, info = env.reset(seed=1)
    pol.reset({})
    actions = []
    for _ in range(3000):
        onboard = {"sightings": info["sightings"]}  # no "pose"
        a = pol.act(obs, onboard)
        obs, _, _, _, info = env.step(a)
        actions.append(a)
        assert abs(info["pose"][0]) < 2700 and abs(info["pose"][1]) < 1800
    changes = np.flatnonzero(np.diff(actions)) + 1
    assert np.all(np.diff(changes) % 150 == 0)


def test_seeded_and_recorded():
    a = collect(None, 1500, seed=4, policy="informed")
    b = collect(None, 1500, seed=4, policy="informed")
    np.testing.assert_array_equal(a.actions, b.actions)
    assert a.meta["policy"] == "informed" and a.meta["policy_params"]["prior_sightings"] == 30.0
    assert a.meta["localizer"] == "ekf"
    u = collect(None, 1500, seed=4, policy={"uniform": {"hold_s": 1.0}})
    assert len(np.unique(u.actions)) > 5


def test_informed_prefers_unexplored_commands_with_sightings():
    pol = InformedPolicy(None, seed=0, coverage_weight=0.0)
    pol.reset()
    cand, score = pol.scores()
    expected, _ = pol.tracker.expected_sightings(*pol.tracker.predict_holds(5.0, 30), 5.0)
    # with no data yet the score grows with the expected sightings
    order = np.argsort(score)
    assert np.all(np.diff(expected[cand][order]) >= -1e-9)
    best = pol.choose()
    pol.tracker.seen[best] = 10_000  # that command now has plenty of data
    assert pol.choose() != best


def test_collect_cli_with_policy_and_params(tmp_path, capsys):
    out = tmp_path / "log.npz"
    assert main(["collect", "--steps", "600", "--seed", "2", "--policy", "informed",
                 "--policy-params", '{"hold_s": 2}', "--out", str(out)]) == 0
    tr = trajectory.load(out)
    assert tr.meta["policy"] == "informed" and tr.meta["policy_params"]["hold_s"] == 2.0
    assert main(["collect", "--steps", "60", "--policy", "sb3:" + str(tmp_path / "none.zip"), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no such file" in err[0] and "none.zip" in err[0]
    assert main(["collect", "--steps", "60", "--policy", "uniform", "--policy-params", '{"x": 1}', "--out", str(out)]) == 2
    assert "unknown parameter 'x'" in capsys.readouterr().err
