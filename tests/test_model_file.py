"""aibo-model/1: round trip, atomic writes, and every validation error of load_params."""

from __future__ import annotations

import json

import numpy as np
import pytest

from learners import model_file
from learners.base import LearnResult
from learners.em.params import paper_start
from learners.model_file import ModelFileError


def _result() -> LearnResult:
    p = paper_start(1 / 30)
    rng = np.random.default_rng(0)
    p = p.with_(action=p.action.__class__(rng.normal(size=(40, 3)), p.action.cov, p.action.dt))
    return LearnResult("em", p, iterations=7, converged=True, loglik=[-3.0, -2.0, -2.5], pruned_observations=4)


def test_round_trip_keeps_contract_keys(tmp_path):
    res = _result()
    path = tmp_path / "m.json"
    model_file.save(res, path)
    doc = json.loads(path.read_text())
    assert doc["format"] == "aibo-model/1" and doc["learner"] == "em"
    for key in ("iterations", "converged", "loglik", "pruned_observations", "effects"):
        assert key in doc
    assert np.asarray(doc["action_model"]["velocities"]).shape == (40, 3)
    assert doc["sensor_model"]["coef"] == [40.0, -0.005]
    assert doc["effects"] == {}
    back = model_file.load_params(path)
    np.testing.assert_allclose(back.action.velocities, res.params.action.velocities, rtol=1e-12)
    np.testing.assert_allclose(back.action.cov, res.params.action.cov)
    assert back.sensor.sigma_height == 10.0 and back.sensor.sigma_angle == 0.2


def test_nan_is_refused_and_old_file_kept(tmp_path):
    path = tmp_path / "m.json"
    model_file.save(_result(), path)
    before = path.read_bytes()
    bad = _result()
    bad.params.action.disp[3, 1] = np.nan
    with pytest.raises(FloatingPointError):
        model_file.save(bad, path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["m.json"]


def _write(tmp_path, mutate):
    path = tmp_path / "m.json"
    model_file.save(_result(), path)
    doc = json.loads(path.read_text())
    mutate(doc)
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize(
    "mutate, field",
    [
        (lambda d: d.update(format="aibo-model/0"), "format"),
        (lambda d: d["action_model"].pop("velocities"), "action_model.velocities"),
        (lambda d: d["action_model"].update(velocities=[[0, 0, 0]] * 39), "action_model.velocities"),
        (lambda d: d["action_model"].update(dt=-1), "action_model.dt"),
        (lambda d: d["action_model"].update(motion_cov=[[1, 2, 0], [0, 1, 0], [0, 0, 1]]), "action_model.motion_cov"),
        (lambda d: d["sensor_model"].update(coef=[]), "sensor_model.coef"),
        (lambda d: d["sensor_model"].update(coef=["a"]), "sensor_model.coef"),
        (lambda d: d["sensor_model"].update(sigma_height=0), "sensor_model.sigma_height"),
        (lambda d: d["sensor_model"].pop("sigma_angle"), "sensor_model.sigma_angle"),
        (lambda d: d["sensor_model"].update(distance_range_mm=[5, 1]), "sensor_model.distance_range_mm"),
    ],
)
def test_bad_model_files_name_file_and_field(tmp_path, mutate, field):
    path = _write(tmp_path, mutate)
    with pytest.raises(ModelFileError) as exc:
        model_file.load_params(path)
    assert str(path) in str(exc.value) and field in str(exc.value)


def test_not_json_and_missing(tmp_path):
    p = tmp_path / "x.json"
    p.write_text("{nope")
    with pytest.raises(ModelFileError, match="not valid JSON"):
        model_file.load_params(p)
    with pytest.raises(ModelFileError, match="file not found"):
        model_file.load_params(tmp_path / "absent.json")
