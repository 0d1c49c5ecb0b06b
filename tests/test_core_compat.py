"""trajectory.check_compatible: which logs may be learned together."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from aibo_core import trajectory
from aibo_core.compat import check_compatible
from aibo_core.trajectory import Trajectory, TrajectoryError


def _log(**changes) -> Trajectory:
    """A tiny valid discrete log with a simulated robot's meta."""
    base = Trajectory(dt=0.1, landmarks=np.array([[0.0, 1000.0], [0.0, -1000.0]]), sighting_frame=np.array([1]),
                      sighting_landmark=np.array([0]), sighting_value=np.array([[30.0, 0.1]]),
                      actions=np.array([0, 1, 0]), attempted=np.eye(3)[:2],
                      meta={"config": {"robot_seed": 0, "noise": "paper-sim", "velocities": None}})
    return replace(base, **changes).validate()


def _continuous(names=("v_mm_s", "omega_rad_s")) -> Trajectory:
    return _log(actions=None, attempted=None, controls=np.zeros((3, 2)), control_names=names)


REFUSED = {
    "landmarks": _log(landmarks=np.array([[0.0, 1000.0], [0.0, -900.0]])),
    "landmarks count": _log(landmarks=np.array([[0.0, 1000.0], [0.0, -1000.0], [5.0, 5.0]])),
    "attempted": _log(attempted=np.eye(3)[:2] * 1.1),
    "attempted size": _log(attempted=np.eye(3)),
    "sensor_kind": _log(sensor_kind="range_mm"),
    "dt": _log(dt=0.05),
    "actions": _continuous(),
}


@pytest.mark.parametrize("name", sorted(REFUSED))
def test_refused_naming_both_files_and_the_field(name):
    with pytest.raises(TrajectoryError) as exc:
        check_compatible([_log(), REFUSED[name]], ["a.npz", "b.npz"])
    field = name.split()[0]
    assert str(exc.value).startswith(f"b.npz: field '{field}': differs from a.npz")


def test_control_names_must_agree():
    with pytest.raises(TrajectoryError, match="b.npz: field 'control_names': differs from a.npz"):
        check_compatible([_continuous(), _continuous(("v_mm_s", "omega_deg_s"))], ["a.npz", "b.npz"])
    assert check_compatible([_continuous(), _continuous()], ["a.npz", "b.npz"]) == []


def test_the_same_robot_is_accepted_silently():
    same = _log(sighting_value=np.array([[31.0, 0.2]]), meta={})  # no meta: nothing to compare
    assert check_compatible([_log(), _log(), same], ["a", "b", "c"]) == []
    assert check_compatible([_log()], ["a"]) == []


def test_other_robot_or_noise_is_a_warning_per_log():
    other = _log(meta={"config": {"robot_seed": 3, "noise": "aibo", "velocities": [[1.0] * 3] * 40}})
    warnings = check_compatible([_log(), _log(), other], ["a.npz", "b.npz", "c.npz"])
    assert len(warnings) == 1 and "\n" not in warnings[0]
    w = warnings[0]
    assert w.startswith("c.npz: meta.config differs from a.npz in robot_seed (3 vs 0), ")
    assert 'noise ("aibo" vs "paper-sim")' in w
    assert "velocities ([[1.0, 1.0, 1.0], [1.0, 1.0... vs null)" in w and len(w) < 300


def test_loaded_logs_of_one_simulated_robot_are_compatible(tmp_path):
    from tests._logs import sim_log

    a, b = sim_log(600, 1), sim_log(600, 2)
    for tr, name in ((a, "a.npz"), (b, "b.npz")):
        trajectory.save(tr, tmp_path / name)
    logs = [trajectory.load(tmp_path / n) for n in ("a.npz", "b.npz")]
    assert check_compatible(logs, ["a.npz", "b.npz"]) == []
