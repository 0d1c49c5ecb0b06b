"""aibo-model/1: round trip, atomic writes, and every validation error of load_model."""

from __future__ import annotations

import json

import numpy as np
import pytest

from aibo_core.trajectory import blind
from learners import load_model
from learners.base import LearnResult
from learners.em.info import FitInfo, FitTimings
from learners.em.learner import EMLearner
from learners.em.options import EMOptions
from learners.model.io import ModelFileError, save_result
from learners.model.model import paper_start
from tests._logs import sim_log


def _result() -> LearnResult:
    p = paper_start([sim_log(300)])
    rng = np.random.default_rng(0)
    p = p.with_(action=p.action.with_values(weights=rng.normal(size=(40, 3))))
    return LearnResult("em", p, iterations=7, converged=True, loglik=[-3.0, -2.0, -2.5], pruned_observations=4)


def test_round_trip_keeps_contract_keys(tmp_path):
    res = _result()
    path = tmp_path / "m.json"
    save_result(res, path)
    doc = json.loads(path.read_text())
    assert doc["format"] == "aibo-model/1" and doc["learner"] == "em"
    for key in ("iterations", "converged", "loglik", "pruned_observations", "effects"):
        assert key in doc
    assert np.asarray(doc["action_model"]["velocities"]).shape == (40, 3)
    assert doc["sensor_model"]["coef"] == [40.0, -0.005, 0.0, 0.0]
    assert doc["effects"] == [] and doc["action_model"]["feature_map"] == "table"
    assert doc["sensor_model"]["kind"] == "height_px" and doc["sensor_model"]["basis"] == "power"
    back = load_model(path)
    np.testing.assert_allclose(back.action.velocities, res.params.action.velocities, rtol=1e-12)
    assert back.max_abs_difference(res.params)["action.weights"] < 1e-12
    np.testing.assert_allclose(back.action.cov, res.params.action.cov)
    assert back.sensor.sigma_size == 10.0 and back.sensor.sigma_bearing == 0.2


def test_nan_is_refused_and_old_file_kept(tmp_path):
    path = tmp_path / "m.json"
    save_result(_result(), path)
    before = path.read_bytes()
    bad = _result()
    bad.params.action.weights[3, 1] = np.nan
    with pytest.raises(FloatingPointError):
        save_result(bad, path)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["m.json"]


def _write(tmp_path, mutate):
    path = tmp_path / "m.json"
    save_result(_result(), path)
    doc = json.loads(path.read_text())
    mutate(doc)
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize(
    "mutate, field",
    [
        (lambda d: d.update(format="aibo-model/0"), "format"),
        (lambda d: d["action_model"].pop("velocities"), "action_model.velocities"),
        (lambda d: d["action_model"].update(velocities=[[0, 0]] * 40), "action_model.velocities"),
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
        load_model(path)
    assert str(path) in str(exc.value) and field in str(exc.value)


def test_not_json_and_missing(tmp_path):
    p = tmp_path / "x.json"
    p.write_text("{nope")
    with pytest.raises(ModelFileError, match="not valid JSON"):
        load_model(p)
    with pytest.raises(ModelFileError, match="file not found"):
        load_model(tmp_path / "absent.json")


def test_same_model_same_bytes_without_wall_clock_timings(tmp_path):
    """Model files keep no timings: the same result with other timings writes the same bytes, and a key
    holding "seconds" that is not a timing is kept (no substring rule)."""
    res = _result()
    res.info = FitInfo(5, 0, {"max_seconds_note": 1}, alias_search={"iterations": 2},
                       timings=FitTimings(3.0, 0.01, alias_search=1.5, uncertainty=2.0, uncertainty_cpu=2.5))
    save_result(res, tmp_path / "a.json")
    res.info.timings = FitTimings(9.0, 0.02, alias_search=4.0)
    save_result(res, tmp_path / "b.json")
    assert (tmp_path / "a.json").read_bytes() == (tmp_path / "b.json").read_bytes()
    assert json.loads((tmp_path / "a.json").read_text())["info"] == {
        "best_iteration": 5, "resumed_from": 0, "options": {"max_seconds_note": 1}, "off_field_fraction": 0.0,
        "undetermined": [], "iterations_all_starts": 0, "alias_search": {"iterations": 2}, "warnings": []}


def test_fit_info_flat_dict_keeps_the_former_keys_in_order():
    """``FitInfo.to_dict()`` is the flat dict results.jsonl and report.json have always held."""
    info = FitInfo(3, 2, {}, starts=[{"iterations": 4}], lag_search={"iterations": 1}, scoring={"converged": True},
                   standard_errors={"a": [1.0]}, information={"condition_number": 2.0}, warnings=["w"],
                   timings=FitTimings(1.0, 0.5, lag_search=0.25, scoring=0.125, uncertainty=0.0, uncertainty_cpu=0.0))
    assert list(info.to_dict()) == [
        "best_iteration", "resumed_from", "first_iteration_seconds", "seconds_per_iteration", "options",
        "off_field_fraction", "undetermined", "starts", "iterations_all_starts", "lag_search_seconds",
        "lag_search", "scoring_seconds", "scoring", "standard_errors", "information", "uncertainty_seconds",
        "uncertainty_cpu_seconds", "warnings"]
    assert info["seconds_per_iteration"] == 0.5 and info.get("alias_search") is None and "scoring" in info



@pytest.mark.parametrize("initial, field", [(5, "initial_state"), ([{"mean": [0, 0, 0], "cov": 5}], "initial_state.0.cov")])
def test_malformed_initial_state_names_the_field(tmp_path, initial, field):
    path = _write(tmp_path, lambda d: d.update(initial_state=initial))
    with pytest.raises(ModelFileError, match=field.replace(".", r"\.")):
        load_model(path)


def test_deeply_nested_json_is_one_line(tmp_path):
    path = tmp_path / "deep.json"
    path.write_text("[" * 100000 + "]" * 100000)
    with pytest.raises(ModelFileError, match="not valid JSON|top level"):
        load_model(path)


def test_em_fit_twice_writes_the_same_model_bytes(tmp_path):
    """Two EM fits of the same log and seed write byte-identical model files, though their timings differ."""
    log = blind(sim_log(300))
    paths = [tmp_path / "a.json", tmp_path / "b.json"]
    for path in paths:
        res = EMLearner(EMOptions(seed=0, max_iter=4)).fit([log])
        assert res.info.timings.first_iteration > 0.0
        save_result(res, path)
    assert paths[0].read_bytes() == paths[1].read_bytes()
    assert "seconds" not in paths[0].read_text()
