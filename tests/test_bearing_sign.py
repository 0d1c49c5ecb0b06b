"""Bearings of the other sign convention (``learners.em.bearing_sign``): a range sensor's fit does not fail on them,
so ``aibo learn`` tells; on logs from a generator this project's simulator did not shape (``tests/_diffdrive.py``)."""

from __future__ import annotations

import json

import numpy as np

from aibo.cli import main
from aibo_core import trajectory
from learners.arrays.batch import make_batch
from learners.em.bearing_sign import negated, sign_errors, sign_warnings
from tests._diffdrive import diff_drive_log

WARNING = "the bearings fit with the opposite sign"


def _learn(tmp_path, capsys, tr) -> tuple[str, dict]:
    trajectory.save(tr, tmp_path / "log.npz")
    assert main(["learn", str(tmp_path / "log.npz"), "--out", str(tmp_path / "m.json")]) == 0
    return capsys.readouterr().err, json.loads((tmp_path / "m.json").read_text())["info"]


def test_clockwise_bearings_are_named_and_counter_clockwise_ones_are_not(tmp_path, capsys):
    """As given: no second fit made. Negated (clockwise): the fit lost the path (the bearings taken for noise) and the
    fit of the bearings negated back is thousands of nats more likely, with the generator's bearing noise."""
    tr = diff_drive_log(120.0, seed=3)
    err, info = _learn(tmp_path, capsys, tr)
    assert WARNING not in err and "bearing_sign" not in info
    err, info = _learn(tmp_path, capsys, negated([tr])[0])
    assert WARNING in err and "clockwise (positive to the right)" in err, err
    record = info["bearing_sign"]
    assert record["loglik_negated"] > record["loglik_given"] + 1000.0
    assert record["sigma_bearing_given"] > 0.3 and record["sigma_bearing_negated"] < 0.05


def test_diagnose_says_so_too(tmp_path, capsys):
    """``aibo diagnose`` checks its base model's bearings as ``aibo learn`` does: the warning on the page, in
    report.json and on stderr; the search goes on with the log as given."""
    trajectory.save(negated([diff_drive_log(120.0, seed=3)])[0], tmp_path / "log.npz")
    out = tmp_path / "diag"
    assert main(["diagnose", str(tmp_path / "log.npz"), "--out", str(out), "--candidates", "floor_drift",
                 "--replicas", "0"]) == 0
    assert WARNING in capsys.readouterr().err
    report = json.loads((out / "report.json").read_text())
    assert report["bearing_sign"]["loglik_negated"] > report["bearing_sign"]["loglik_given"] + 1000.0
    assert any(w.startswith(WARNING) for w in report["warnings"]) and WARNING in (out / "report.html").read_text()


def test_known_answers_on_a_straight_path():
    """Landmarks seen from poses on the x axis: bearings as given fit exactly, negated ones miss by twice the bearing
    (wrapped); too few sightings: no verdict. The warning only beyond its margin."""
    tr = diff_drive_log(60.0, seed=1)
    batch = make_batch([tr])
    poses = np.zeros((tr.n_frames + 1, 3))
    poses[:, 0] = np.linspace(0.0, 1000.0, tr.n_frames + 1)
    to = batch.landmarks[batch.sight_landmark] - poses[batch.sight_pose, :2]
    exact = np.arctan2(to[:, 1], to[:, 0])
    batch.sight_value[:, 1] = exact
    given, flipped = sign_errors(batch, poses)
    assert given < 1e-12 and flipped == np.median(np.abs(np.angle(np.exp(-2j * exact[batch.used]))))
    batch.sight_value[:, 1] = -exact
    assert sign_errors(batch, poses)[1] < 1e-12
    batch.used[:] = False
    batch.used[:49] = True
    assert sign_errors(batch, poses) is None
    record = {"loglik_given": -100.0, "loglik_negated": -91.0, "sigma_bearing_given": 0.7, "sigma_bearing_negated": 0.02}
    assert sign_warnings(record) == [] and sign_warnings(None) == []
    assert "11 nats more likely" in sign_warnings({**record, "loglik_negated": -89.0})[0]
