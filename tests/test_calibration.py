"""scripts/calibration.py's arithmetic (coverage, bias, bias / SE on known inputs; truths in the learner's
parametrization) and the final fit it shares with ``aibo diagnose`` (``learners.discrepancy.final.diagnosed``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests._scripts import load_script


def _load():
    return load_script("calibration")


def test_coverage_bias_and_their_standard_errors_on_known_inputs():
    cal = _load()
    values = [1.0, 2.0, 3.0, 4.0]  # truth 2: errors -1, 0, 1, 2 (mean 0.5); spread sd = 1.291
    ses = [0.5, 0.5, None, 1.5]  # the third has no SE: its interval's half-width / 1.96 (0.5) stands in
    intervals = [[0.0, 2.0], [1.5, 2.5], [3.0 - 0.5 * cal.Z95, 3.0 + 0.5 * cal.Z95], None]  # in, in, out, missing
    s = cal.summary(values, ses, intervals, 2.0)
    assert (s["n"], s["missing"], s["covered"]) == (4, 1, 2)
    assert s["coverage"] == pytest.approx(2 / 3) and s["coverage_se"] == pytest.approx(math.sqrt(2 / 9 / 3))
    assert s["bias"] == pytest.approx(0.5)
    spread = float(np.std(values, ddof=1))
    assert s["bias_mcse"] == pytest.approx(spread / 2)
    assert s["se"] == pytest.approx((0.5 + 0.5 + 0.5 + 1.5) / 4)
    assert s["ratio"] == pytest.approx(0.5 / 0.75) and s["ratio_mcse"] == pytest.approx(spread / 2 / 0.75)
    assert s["spread_ratio"] == pytest.approx(spread / 0.75)


def test_an_interval_holding_the_truth_at_its_end_covers_it():
    cal = _load()
    s = cal.summary([0.1, 0.1], [None, None], [[0.0, 0.1], [0.1, 0.2]], 0.1)  # a grid interval ends at the truth
    assert s["coverage"] == 1.0 and s["bias"] == 0.0 and s["se"] == pytest.approx(0.1 / (2 * cal.Z95))


def test_truths_are_compared_in_the_learners_parametrization():
    cal = _load()
    scale = cal.truth("beacon_height_scale", {"scale": [1.02, 0.98, 1.01, 0.99]})["scale"]
    assert np.exp(np.mean(np.log(scale))) == pytest.approx(1.0)  # geometric mean 1, as the log-contrast group
    assert np.allclose(np.asarray(scale) / scale[0], np.array([1.02, 0.98, 1.01, 0.99]) / 1.02)
    offsets = cal.truth("landmark_bearing_offset", {"offset_rad": [0.02, 0.0, 0.0, 0.0]})["offset_rad"]
    assert np.allclose(offsets, [0.015, -0.005, -0.005, -0.005])  # mean 0, as the contrast group
    assert cal.truth("landmark_bias", {"sigma_rel": 0.05, "tau_s": 8.0}) == {"sigma_rel": 0.05, "tau_s": 8.0}
    # a lag of discrete commands acts in whole frames: 0.15 s at 30 frames/s is 5 frames, the same model as 1/6 s
    assert cal.truth("actuation_lag", {"lag_s": 0.15}, dt=1 / 30)["lag_s"] == pytest.approx(1 / 6)
    assert cal.truth("actuation_lag", {"lag_s": 0.1}, dt=1 / 30)["lag_s"] == pytest.approx(0.1)  # 3 frames exactly
    assert cal.truth("actuation_lag", {"lag_s": 0.15})["lag_s"] == 0.15  # continuous commands: as simulated


def test_the_table_counts_the_named_logs_and_reports_array_parameters_per_component_and_preset():
    cal = _load()

    def row(log, named, value=None):
        r = {"effect": "floor_drift", "log": log, "preset": cal.PRESETS[log % 2], "truth": {"drift_mm_s": [12.0, 0.0]},
             "named": ["floor_drift"] if named else []}
        if named:
            r["effects"] = [{"name": "floor_drift", "intervals": {"drift_mm_s": {
                "value": value, "se": [1.0, 1.0], "interval_95": [[v - 2 for v in value], [v + 2 for v in value]]}}}]
        return r

    md = cal.table([row(0, True, [11.0, 0.5]), row(1, False), row(2, True, [13.0, 3.0])])
    lines = [line for line in md.splitlines() if line.startswith("| floor_drift")]
    assert [line.split(" | ")[1:3] for line in lines] == [["drift_mm_s[0]", "aibo"], ["drift_mm_s[0]", "paper-sim"],
                                                          ["drift_mm_s[1]", "aibo"], ["drift_mm_s[1]", "paper-sim"]]
    assert "| 2 of 2 |" in lines[0] and "| 0 of 1 |" in lines[1]
    assert "100% +- 0% (2 of 2)" in lines[0] and "50% +- 35% (1 of 2)" in lines[2]  # 0 is outside [1, 5]
    assert "+1.75" in lines[2]  # bias 1.75 over SE 1


def test_the_rows_of_every_process_are_read_together_in_log_order(tmp_path):
    from aibo_core.atomic import write_jsonl

    cal = _load()
    write_jsonl(tmp_path / "rows.jsonl", [{"effect": "velocity_fade", "log": 0}, {"effect": "velocity_fade", "log": 1}])
    write_jsonl(tmp_path / "rows-from-50.jsonl", [{"effect": "velocity_fade", "log": 50}])
    write_jsonl(tmp_path / "rows-from-25.jsonl", [{"effect": "velocity_fade", "log": 25}])
    assert [r["log"] for r in cal.all_rows(tmp_path)] == [0, 1, 25, 50]


def test_every_strength_is_a_valid_simulator_and_learner_parameter_set():
    from aibo_gym.config import make_config
    from learners.model.effects import EFFECT_MODELS

    cal = _load()
    assert set(cal.STRENGTH) == set(EFFECT_MODELS) - {"wall_contact", "angle_bias"}
    for name, params in cal.STRENGTH.items():
        assert set(params) == set(EFFECT_MODELS[name].PARAMS)
        make_config({"effects": {name: params}})  # valid for the simulator (ValueError otherwise)


def test_diagnosed_is_the_final_fit_of_the_searched_model_with_each_named_effects_intervals():
    """``learners.discrepancy.final.diagnosed`` (what ``aibo diagnose`` and the calibration study call): the final fit
    warm-started from ``found["model"]`` on ``found["logs"]`` with the search's stop rule; a named effect's parameters
    are the final fit's, its Wald intervals come from that fit's standard errors, a grid parameter's from the search's
    profile (refined in frames for discrete commands), and ``parameters_when_named`` from the candidate."""
    from learners.arrays.batch import make_batch
    from learners.discrepancy.candidate import Candidate
    from learners.discrepancy.effect_sizes import ROBUST_WALD, Z95
    from learners.discrepancy.final import FINAL_FIT_STAGE, PROFILE_STAGE, diagnosed, final_options
    from learners.discrepancy.fitting import SEARCH_PATIENCE
    from learners.em.learner import EMLearner
    from learners.em.options import EMOptions
    from learners.model.catalogue import ActuationLag, VelocityFade
    from tests._logs import sim_log

    tr = sim_log(3000)
    opts = EMOptions(seed=0, lag_search=False)
    fopts = final_options(opts)
    assert (fopts.starts, fopts.alias_search, fopts.patience, fopts.min_improvement) == (1, False, SEARCH_PATIENCE, 0.1)
    base = EMLearner(EMOptions(max_iter=15, lag_search=False)).fit([tr]).params
    batch = make_batch([tr])
    model = base.with_effect(VelocityFade.start(batch)).with_effect(ActuationLag.start(batch))
    profile = [[0.0, 0.1, 0.2, 0.3], [-9.0, 0.0, -1.0, -30.0]]  # the grid's training log-likelihoods
    named = [Candidate("velocity_fade", {"fade_per_min": 0.004}, 5.0, 1.0, 1, 0.001, model=model),
             Candidate("actuation_lag", {"lag_s": 0.1}, 9.0, 2.0, 1, 1e-5, model=model, profile={"lag_s": profile})]
    out = diagnosed({"model": model, "logs": [tr], "named": named}, opts)
    assert [e["name"] for e in out.effects] == ["velocity_fade", "actuation_lag"]
    # the lag of these discrete commands gets the whole log's profile in frames (``profile.refine_grid_intervals``)
    assert list(out.seconds) == [FINAL_FIT_STAGE, PROFILE_STAGE] and out.profiled == ["actuation_lag"]
    fade, lag = out.effects
    fisher = out.result.info["standard_errors"]["effects.velocity_fade.fade_per_min"]
    se = out.result.info["robust_standard_errors"]["effects.velocity_fade.fade_per_min"]
    value = float(out.result.params.effect("velocity_fade").fade_per_min)
    iv = fade["intervals"]["fade_per_min"]
    assert fade["parameters"] == {"fade_per_min": value} and iv["value"] == value and iv["se"] == pytest.approx(se)
    assert iv["method"] == ROBUST_WALD and iv["interval_95"] == pytest.approx([value - Z95 * se, value + Z95 * se])
    assert se >= fisher and iv["se_fisher"] == pytest.approx(fisher)  # the larger of Fisher and sandwich; Fisher kept
    assert iv["interval_95_fisher"] == pytest.approx([value - Z95 * fisher, value + Z95 * fisher])
    assert fade["parameters_when_named"] == {"fade_per_min": 0.004}
    lag_iv = lag["intervals"]["lag_s"]
    assert lag_iv["grid_interval_95"] == [0.0, 0.3]  # the search's: within 1.92 nats 0.1 and 0.2, widened by a step
    assert lag_iv["grid_step"] == pytest.approx(tr.dt) and lag_iv["interval_95"][0] <= lag_iv["value"] <= lag_iv["interval_95"][1]
    assert lag_iv["value"] == out.result.params.effect("actuation_lag").lag_s  # the value stated is the model's
    assert lag["parameters_when_named"] == {"lag_s": 0.1}


def test_strength_overrides_set_one_parameter_and_refuse_what_is_not_one():
    cal = _load()
    cal.set_strength(["actuation_lag.lag_s=0.15", "beacon_height_scale.scale=[1.04, 0.96, 1.0, 1.0]"])
    assert cal.STRENGTH["actuation_lag"] == {"lag_s": 0.15}
    assert cal.STRENGTH["beacon_height_scale"]["scale"] == [1.04, 0.96, 1.0, 1.0]
    assert cal.STRENGTH["landmark_bias"] == {"sigma_rel": 0.05, "tau_s": 8.0}  # the others as they were
    for bad in ("actuation_lag.lag=0.15", "actuation_lag.lag_s", "nothing.x=1", "actuation_lag.lag_s=fast"):
        with pytest.raises(ValueError, match="--strength"):
            cal.set_strength([bad])


def test_the_final_fit_starts_from_the_searchs_model_and_from_learns_and_keeps_the_more_likely(monkeypatch):
    """``final_fit``: one fit from the search's model and one from ``found["learned"]``'s (``aibo learn``'s model of the
    same logs) action model, sensor model and start poses with the search's effects, its curve held until EM has
    converged and then freed; the more likely kept. Without ``found["learned"]``, the search's model alone."""
    from learners.arrays.batch import make_batch
    from learners.discrepancy import final
    from learners.discrepancy.fitting import train_loglik
    from learners.em.learner import EMLearner
    from learners.em.options import EMOptions
    from learners.model.catalogue import VelocityFade
    from tests._logs import sim_log

    tr = sim_log(1500)
    learned = EMLearner(EMOptions(max_iter=5, lag_search=False)).fit([tr]).params
    searched = EMLearner(EMOptions(max_iter=2, lag_search=False)).fit([tr]).params
    searched = searched.with_effect(VelocityFade.start(make_batch([tr])))
    assert not np.allclose(learned.action.weights, searched.action.weights)
    starts, fits = [], []

    class Recording(EMLearner):
        def fit(self, logs, init=None, **kw):
            starts.append(init)
            fits.append(super().fit(logs, init=init, **kw))
            return fits[-1]

    monkeypatch.setattr(final, "EMLearner", Recording)
    opts = EMOptions(seed=0, lag_search=False, max_iter=3)
    kept, record = final.final_fit({"model": searched, "logs": [tr], "learned": learned}, opts)
    from_search, from_learned, from_held = starts
    assert from_search is searched
    assert from_learned.action is learned.action and from_learned.sensor is learned.sensor
    assert from_learned.init is learned.init and from_learned.effects == searched.effects
    # learn's start: EM with learn's curve held (HOLD_LEARNED_CURVE), then the final fit from where it stopped
    held = fits[1]
    assert np.array_equal(held.params.sensor.coef, learned.sensor.coef) and from_held is held.params
    assert not np.array_equal(fits[2].params.sensor.coef, learned.sensor.coef)
    assert not held.info.get("standard_errors") and fits[2].info.get("standard_errors")
    fits = [fits[0], fits[2]]
    ll = [train_loglik(f.params, [tr]) for f in fits]
    assert ll[0] != ll[1] and kept is fits[int(np.argmax(ll))]
    # the record report.json["final_fit_starts"] states: each start's likelihood, the more likely marked kept
    assert [r["start"] for r in record] == list(final.START_NAMES)
    assert [r["loglik"] for r in record] == pytest.approx(ll)
    assert [r["kept"] for r in record] == [v == max(ll) for v in ll]
    # in a worker pool (``aibo diagnose``'s, the starts side by side): the same fits, the same start kept
    from aibo_core.workers import process_pool

    with process_pool(2) as pool:
        pooled, pooled_record = final.final_fit({"model": searched, "logs": [tr], "learned": learned}, opts, pool)
    assert pooled_record == record and np.array_equal(pooled.params.action.weights, kept.params.action.weights)
    starts.clear()
    _, record = final.final_fit({"model": searched, "logs": [tr]}, opts)
    assert starts == [searched] and record == [{"start": final.START_NAMES[0], "loglik": None, "kept": True}]


def test_the_table_gives_the_coverage_of_the_intervals_the_report_does_not_warn_about():
    """A log whose effect moved outside its final interval since it was named (``effect_sizes.moved_since_named``,
    one of the report's warnings about the effect) counts in the coverage, and not in the "not warned" one."""
    cal = _load()

    def row(log, value, when_named):
        return {"effect": "turn_heading_noise", "log": log, "preset": "paper-sim", "truth": {"gain_s": 1.5},
                "named": ["turn_heading_noise"],
                "effects": [{"name": "turn_heading_noise", "parameters_when_named": {"gain_s": when_named},
                             "intervals": {"gain_s": {"value": value, "se": 0.5,
                                                      "interval_95": [value - 1.0, value + 1.0]}}}]}

    rows = [row(1, 1.4, 1.3), row(3, 6.0, 1.1), row(5, 2.0, 1.9)]  # log 3: named at 1.1, 6.0 [5, 7] in the final fit
    assert [cal.warned(r) for r in rows] == [False, True, False]
    line = next(line for line in cal.table(rows).splitlines() if line.startswith("| turn_heading_noise"))
    assert "67% +- 27% (2 of 3)" in line and line.endswith("| 100% (2 of 2); misses warned: 1 of 1 |")
