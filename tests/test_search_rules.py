"""The decision rules of the discrepancy search that do not need a fit: the backward check (``prune``), the
plausibility of a fitted bias, and the warning of a fit in a world that does not fit the field."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from learners.discrepancy import search as search_module
from learners.discrepancy.candidate import Candidate, Verdict
from learners.discrepancy.grid import PAST_PEAK_NATS, walk_profile
from learners.discrepancy.search import prune
from learners.em.learner import MAX_OFF_FIELD, field_warnings
from learners.model.landmark_bias import MAX_PLAUSIBLE_SIGMA, LandmarkBias
from tests._search_stand_ins import StandInContext as _Context
from tests._search_stand_ins import StandInEffect as _Effect
from tests._search_stand_ins import StandInModel as _Model


def _run(names, train_ll, heldout_ll, factor=None):
    """prune() on stand-ins (``factor``: the Fisher information's overstatement of every effect's parameters that its
    robust likelihood ratio measured when it was named; None: that check did not run)."""
    named = [Candidate(n, {}, 0.0, 0.0, 1, 0.0) for n in names]
    if factor is not None:
        for c in named:
            c.checks.append(Verdict("robust likelihood ratio", True, overstatement=factor))
    full = _Model(tuple(_Effect(n) for n in names))
    model, ll = prune(named, full, train_ll[frozenset(names)], _Context(train_ll, heldout_ll), None, lambda s: None)
    return [c.name for c in named], model, ll


def test_the_backward_check_drops_a_stand_in_and_keeps_what_earns_its_place():
    """'bias' was named first but, given 'outliers', gains 0.5 nats (p 0.3): dropped; 'outliers' given 'bias'
    gains 40 nats train and 30 held-out: kept, and the returned model is the reduced refit."""
    s = frozenset
    train = {s({"bias", "outliers"}): -1000.0, s({"outliers"}): -1000.5, s({"bias"}): -1040.0}
    held = {s({"bias", "outliers"}): -900.0, s({"outliers"}): -899.0, s({"bias"}): -930.0}
    kept, model, ll = _run(["bias", "outliers"], train, held)
    assert kept == ["outliers"]
    assert [e.name for e in model.effects] == ["outliers"] and ll == -1000.5


def test_the_backward_check_keeps_two_effects_that_both_matter():
    s = frozenset
    train = {s({"a", "b"}): -1000.0, s({"b"}): -1030.0, s({"a"}): -1025.0}
    held = {s({"a", "b"}): -900.0, s({"b"}): -920.0, s({"a"}): -915.0}
    kept, model, ll = _run(["a", "b"], train, held)
    assert kept == ["a", "b"] and ll == -1000.0


def test_the_backward_check_is_the_robust_test_that_named_the_effects():
    """'a' gains 10 nats given 'b' (p 6e-6: kept by the plain test at 0.01 / 2) but its robust test found, when it was
    named, that the information overstates the data's by 4: 2.5 nats count (p 0.025), dropped; 'b''s 30 count as 7.5
    (p 1e-4), kept."""
    s = frozenset
    train = {s({"a", "b"}): -1000.0, s({"b"}): -1010.0, s({"a"}): -1030.0}
    held = {s({"a", "b"}): -900.0, s({"b"}): -905.0, s({"a"}): -920.0}
    assert _run(["a", "b"], train, held)[0] == ["a", "b"]
    assert _run(["a", "b"], train, held, factor=4.0)[0] == ["b"]


def test_the_backward_check_drops_an_effect_that_loses_on_the_held_out_half():
    """Significant on the training half (+20 nats) but worse held out (-2 nats): an over-fit, dropped."""
    s = frozenset
    train = {s({"a", "b"}): -1000.0, s({"b"}): -1030.0, s({"a"}): -1020.0}
    held = {s({"a", "b"}): -900.0, s({"b"}): -920.0, s({"a"}): -898.0}
    kept, _, _ = _run(["a", "b"], train, held)
    assert kept == ["a"]


def test_an_effect_the_later_ones_made_implausible_is_dropped_before_the_backward_check():
    """'bias' was credible when named (round 2) but the refit with 'outliers' took it to 33%: dropped and the model
    refitted without it, even though it still gains on both halves (measured on a false-sightings log, seed 11)."""
    s = frozenset
    train = {s({"bias", "outliers"}): -1000.0, s({"outliers"}): -1100.0}
    named = [Candidate(n, {}, 0.0, 0.0, 1, 0.0) for n in ("outliers", "bias")]
    full = _Model((_Effect("outliers"), _Effect("bias", why_implausible="sigma_rel 0.33 is no bias")))
    said = []
    model, ll = prune(named, full, train[s({"bias", "outliers"})], _Context(train, {}), None, said.append)
    assert [c.name for c in named] == ["outliers"] and [e.name for e in model.effects] == ["outliers"]
    assert ll == -1100.0 and said == ["dropped: bias (given the others, sigma_rel 0.33 is no bias)"]


def test_an_effect_made_implausible_by_a_drop_is_dropped_too(monkeypatch):
    """Implausibility is checked again after every drop (the drop refits the rest): dropping 'fade' (it gains 0.1
    nats) leaves 'bias' at 30% (no bias), which is then dropped before any other test."""
    s = frozenset
    train = {s({"fade", "bias"}): -1000.0, s({"bias"}): -1000.1, s({"fade"}): -1050.0, s(): -1050.0}
    held = {s({"fade", "bias"}): -900.0, s({"bias"}): -899.0, s({"fade"}): -950.0}

    def drop_job(args):
        reduced = args[1].without_effect(args[0])
        if args[0] == "fade":  # the refit without the fade pushes the bias out of its credible range
            reduced = _Model((_Effect("bias", why_implausible="sigma_rel 0.30 is no bias"),))
        return reduced, train[s(e.name for e in reduced.effects)]

    monkeypatch.setattr(search_module, "_drop_job", drop_job)
    named = [Candidate(n, {}, 0.0, 0.0, 1, 0.0) for n in ("fade", "bias")]
    said = []
    model, ll = prune(named, _Model((_Effect("fade"), _Effect("bias"))), -1000.0, _Context(train, held), None,
                      said.append)
    assert named == [] and model.effects == () and ll == -1050.0, said
    assert said[-1] == "dropped: bias (given the others, sigma_rel 0.30 is no bias)"


def test_a_named_effect_whose_intervals_hold_its_off_value_is_said_to_be_weak():
    from learners.discrepancy.effect_sizes import holds_off

    fade = {"fade_per_min": {"value": 0.0002, "se": 0.0024, "interval_95": [-0.0045, 0.0049], "method": "wald"}}
    assert "not distinguishable from none" in holds_off("velocity_fade", fade, {"fade_per_min": 0.0})
    assert holds_off("velocity_fade", fade, {"fade_per_min": 0.01}) == ""  # 0.01 is outside: the fade is there
    drift = {"drift_mm_s": {"value": [15.0, 0.5], "se": [1.0, 1.0], "interval_95": [[13.0, -1.5], [17.0, 2.5]],
                            "method": "wald"}}
    assert holds_off("floor_drift", drift, {"drift_mm_s": [0.0, 0.0]}) == ""  # one entry off zero: there
    undetermined = {"fade_per_min": {"value": 0.0, "se": None, "interval_95": None, "method": None}}
    assert holds_off("velocity_fade", undetermined, {"fade_per_min": 0.0}) == ""


def test_a_bias_of_more_than_a_fifth_of_the_size_is_not_credible():
    assert LandmarkBias(0.05, 8.0).implausible() == ""
    assert LandmarkBias(MAX_PLAUSIBLE_SIGMA, 8.0).implausible() == ""
    note = LandmarkBias(0.47, 21.6).implausible()
    assert "0.47" in note and "wrong world" in note


def test_a_bias_that_holds_for_minutes_is_not_a_pass_to_pass_bias():
    from learners.model.landmark_bias import MAX_PLAUSIBLE_TAU_S

    assert LandmarkBias(0.045, 34.6).implausible() == ""  # MRCLAM robot 4, the longest real one measured
    assert LandmarkBias(0.05, MAX_PLAUSIBLE_TAU_S).implausible() == ""
    note = LandmarkBias(0.02, 104.1).implausible()  # per-beacon height factors of 2% (5-minute log, seed 2005)
    assert "104 s" in note and "beacon_height_scale" in note


def test_a_bias_gone_within_a_second_is_white_noise_not_a_bias():
    from learners.model.landmark_bias import MIN_PLAUSIBLE_TAU_S

    assert LandmarkBias(0.005, 4.24).implausible() == ""  # MRCLAM robot 2's first half, the range curve freed
    assert LandmarkBias(0.05, MIN_PLAUSIBLE_TAU_S).implausible() == ""
    note = LandmarkBias(0.0067, 0.695).implausible()  # MRCLAM robot 4's whole-log final fit, named at 35.6 s
    assert "0.69 s" in note and "white noise" in note


@pytest.mark.parametrize("frac, warned", [(0.0, False), (MAX_OFF_FIELD, False), (0.975, True)])
def test_a_fit_off_the_field_is_warned(frac, warned):
    w = field_warnings(frac)
    assert bool(w) == warned
    if warned:
        assert "98% of smoothed poses" in w[0]


def test_effect_intervals_are_wald_intervals_clipped_to_the_domain():
    from learners.discrepancy.effect_sizes import Z95, effect_intervals
    from learners.model.model import Model

    model = Model(action=None, sensor=None, init=(), effects=(LandmarkBias(0.05, 8.0),))
    se = {"effects.landmark_bias.sigma_rel": 0.01, "effects.landmark_bias.tau_s": None}
    iv = effect_intervals(model, "landmark_bias", se)
    assert iv["sigma_rel"]["interval_95"] == pytest.approx([0.05 - Z95 * 0.01, 0.05 + Z95 * 0.01])
    assert iv["tau_s"] == {"value": 8.0, "se": None, "interval_95": None, "method": None}  # undetermined: none
    wide = effect_intervals(model, "landmark_bias", {"effects.landmark_bias.sigma_rel": 0.04})
    # 0.05 +- 1.96 x 0.04 crosses 0: a parameter fitted on the log scale gets the Wald interval of its logarithm
    assert wide["sigma_rel"]["interval_95"] == pytest.approx([0.05 * np.exp(-Z95 * 0.8), 0.05 * np.exp(Z95 * 0.8)])
    assert wide["sigma_rel"]["clipped"] and "log scale" in wide["sigma_rel"]["method"]
    assert not iv["sigma_rel"]["clipped"] and iv["sigma_rel"]["method"] == "wald"


def test_an_interval_that_crosses_the_domain_is_clipped_where_the_parameter_is_not_fitted_on_the_log_scale():
    """A lag (fitted as it is, domain [0, 60] s) of 0.02 +- 0.03 s: [0, 0.0788], the method plain Wald."""
    from learners.discrepancy.effect_sizes import Z95, effect_intervals
    from learners.model.catalogue import ActuationLag
    from learners.model.model import Model

    model = Model(action=None, sensor=None, init=(), effects=(ActuationLag(0.02),))
    iv = effect_intervals(model, "actuation_lag", {"effects.actuation_lag.lag_s": 0.03})["lag_s"]
    assert iv["interval_95"] == pytest.approx([0.0, 0.02 + Z95 * 0.03]) and iv["clipped"] and iv["method"] == "wald"


def test_a_grid_parameter_gets_the_profile_likelihood_interval():
    from learners.discrepancy.effect_sizes import effect_intervals, profile_interval
    from learners.model.catalogue import ActuationLag
    from learners.model.model import Model

    grid = [0.0, 0.1, 0.2, 0.3, 0.4, 0.5]
    # within 1.92 nats of the best (0.2): 0.1 (-1.9) and 0.3 (-0.5); 0.4 (-2.0) just outside; the walk stopped there.
    # The interval's ends lie between 0.0 and 0.1 and between 0.3 and 0.4: widened to those grid values
    lls = [-30.0, -1.9, 0.0, -0.5, -2.0]
    assert profile_interval(grid, lls) == [0.0, 0.4]
    assert profile_interval(grid, [-25.0, 0.0, -25.0]) == [0.0, 0.2]  # a sharp profile: not [0.1, 0.1]
    assert profile_interval(grid, [0.0, -25.0]) == [0.0, 0.1]  # at the grid's end: the end itself
    model = Model(action=None, sensor=None, init=(), effects=(ActuationLag(0.2),))
    iv = effect_intervals(model, "actuation_lag", {}, {"lag_s": [grid[:5], lls]})["lag_s"]
    assert iv["interval_95"] == [0.0, 0.4] and iv["se"] is None and iv["method"].startswith("profile")
    assert iv["grid_step"] == 0.1 and "step 0.1" in iv["method"] and "refined" not in iv["method"]
    assert effect_intervals(model, "actuation_lag", {})["lag_s"]["interval_95"] is None  # no profile: no interval
    # the final fit's polish refined it between the grid's values: the method says so, the interval holds it
    refined = Model(action=None, sensor=None, init=(), effects=(ActuationLag(0.237),))
    iv = effect_intervals(refined, "actuation_lag", {}, {"lag_s": [grid[:5], lls]})["lag_s"]
    assert iv["value"] == 0.237 and "refined between them" in iv["method"]
    assert iv["interval_95"][0] <= 0.237 <= iv["interval_95"][1]


def test_base_shift_reports_the_largest_velocity_and_curve_changes_in_file_units():
    from dataclasses import replace

    import numpy as np

    from learners.discrepancy.effect_sizes import base_shift
    from learners.oracle import OracleLearner
    from tests._logs import sim_log

    before = OracleLearner().fit([sim_log(3000)]).params
    w = np.array(before.action.weights, dtype=float)
    dt = before.action.dt
    w[5] += np.array([3.0, -2.0, 0.1]) * dt  # mm/s, mm/s, rad/s on command 5
    w[7] += np.array([-1.0, 4.0, 0.0]) * dt
    coef = np.array(before.sensor.coef, dtype=float)
    coef[0] += 2.0  # the curve 2 px higher at every distance (either basis)
    after = before.with_(action=before.action.with_values(weights=w), sensor=replace(before.sensor, coef=coef))
    shift = base_shift(before, after)
    assert shift["velocities_max_abs"] == pytest.approx([3.0, 4.0, 0.1])
    n = len(w)
    assert shift["velocities_rms"] == pytest.approx(np.sqrt(np.array([9.0 + 1.0, 4.0 + 16.0, 0.01]) / n))
    assert shift["sensor_curve_max_abs"] == pytest.approx(2.0) and shift["sensor_unit"] == "px"


def test_a_grid_profile_stops_past_its_peak_and_walks_a_flat_one_whole():
    grid = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5)
    peaked = dict(zip(grid, (0.0, 246.0, 457.0, 371.0, 181.0, 15.0)))  # actuation_lag on MRCLAM robot 1
    seen = []
    lls = walk_profile(grid, lambda g: seen.append(g) or peaked[g])
    assert seen == [0.0, 0.1, 0.2, 0.3] and lls == [0.0, 246.0, 457.0, 371.0]
    # within PAST_PEAK_NATS of the best it goes on: a flat or noisy profile is walked whole
    flat = [0.0, 0.5, -0.3, 0.2, PAST_PEAK_NATS / 2, 0.0]
    assert walk_profile(grid, lambda g: flat[grid.index(g)]) == flat


def test_walked_keeps_what_the_walk_in_order_evaluates_of_points_computed_ahead():
    """``grid.walked`` and ``GridWalk``: the points a pool computes ahead of the walk, cut where the walk stops."""
    from learners.discrepancy.grid import GridWalk, walked

    peaked = [0.0, 246.0, 457.0, 371.0, 181.0, 15.0]
    assert walked(peaked) == 4 and walked(peaked[:3]) == 3 and walked([0.0, -PAST_PEAK_NATS - 1]) == 2
    w = GridWalk("actuation_lag", None, None)
    assert [w.next_value(), w.next_value()] == [0, 1]
    w.record(1, (None, 246.0))  # out of order: the walk waits for the first value
    assert not w.done() and w.next_value() == 2
    for k in (0, 2):
        w.record(k, (None, peaked[k]))
    assert not w.done() and w.next_value() == 3
    w.record(3, (None, 371.0))
    assert w.done() and w.next_value() is None


def test_a_pool_walks_a_grid_candidate_as_one_process_does():
    """``run_round`` on two workers (a grid candidate's points as jobs of their own) names the same effects with the
    same profiles and gains as the search in one process, on a wheeled robot's log with a 0.2 s lag."""
    from aibo_gym.collect_wheeled import collect_wheeled
    from learners.discrepancy.search import search
    from learners.em.options import EMOptions

    tr = collect_wheeled({"effects": {"actuation_lag": {"lag_s": 0.2}}, "start_pose": "random"}, 3000, 7)
    found = [search([tr], ["actuation_lag", "velocity_fade", "floor_drift"], EMOptions(), jobs=j, progress=lambda s: None)
             for j in (1, 2)]
    assert [c.name for c in found[0]["named"]] == [c.name for c in found[1]["named"]] == ["actuation_lag"]
    for one, two in zip(*(f["rounds"] for f in found)):
        for a, b in zip(one, two):
            assert (a.name, a.profile, a.gain_train, a.gain_heldout, a.significant) == \
                (b.name, b.profile, b.gain_train, b.gain_heldout, b.significant)
            assert [v.name for v in a.checks] == [v.name for v in b.checks]


def test_a_final_estimate_outside_its_interval_from_the_value_when_named_is_said():
    """A rate named at 0.072 on the training half whose final fit says 0.0124 +- 0.004: the report warns (the two
    fits disagree) and states the final value; within the interval, nothing is said."""
    from learners.discrepancy.effect_sizes import moved_since_named

    iv = {"rate": {"value": 0.0124, "se": 0.002, "interval_95": [0.0085, 0.0163], "method": "wald"}}
    why = moved_since_named("false_sightings", iv, {"rate": 0.072})
    assert why.startswith("false_sightings:") and "rate 0.072 when named, 0.0124 in the final fit" in why
    assert moved_since_named("false_sightings", iv, {"rate": 0.013}) == ""
    arr = {"scale": {"value": [1.0, 1.1], "se": [0.01, 0.01], "interval_95": [[0.98, 1.08], [1.02, 1.12]]}}
    assert moved_since_named("beacon_height_scale", arr, {"scale": [1.0, 1.2]}) != ""  # one element outside
    assert moved_since_named("x", {"a": {"value": 1.0, "interval_95": None}}, {"a": 5.0}) == ""  # no interval
    # a lag named on the search's 0.1 s grid is known to 0.05 s: MRCLAM robot 1's 0.2 agrees with 0.224 [0.217, 0.233]
    lag = {"lag_s": {"value": 0.224, "se": None, "interval_95": [0.217, 0.233]}}
    assert moved_since_named("actuation_lag", lag, {"lag_s": 0.2}) == ""
    assert "lag_s 0.1 when named" in moved_since_named("actuation_lag", lag, {"lag_s": 0.1})


def test_the_disagreement_since_named_allows_for_the_training_halfs_own_error():
    """A drift named at 8.5 mm/s on the training half, 12.0 +- 1.4 in the final fit (interval [9.26, 14.74]): with the
    training half's robust error 3.0 the difference's error is sqrt(3^2 - 1.4^2) = 2.65 (nested estimates, Hausman),
    its allowance +-5.2: nothing said. With the error half the sightings would give (1.4 sqrt 2: the allowance is the
    interval itself), or none known, it is said; far beyond the allowance, said either way."""
    from learners.discrepancy.effect_sizes import moved_since_named, read_with_care

    iv = {"drift_mm_s": {"value": [12.0, 0.0], "se": [1.4, 1.4], "interval_95": [[9.256, -2.744], [14.744, 2.744]]}}
    named = {"drift_mm_s": [8.5, 0.3]}
    assert moved_since_named("floor_drift", iv, named, {"drift_mm_s": [3.0, 3.0]}) == ""
    assert moved_since_named("floor_drift", iv, named, {"drift_mm_s": [1.4 * 2 ** 0.5] * 2}) != ""
    assert moved_since_named("floor_drift", iv, named) != "" and moved_since_named("floor_drift", iv, named, {}) != ""
    assert moved_since_named("floor_drift", iv, {"drift_mm_s": [4.0, 0.3]}, {"drift_mm_s": [3.0, 3.0]}) != ""
    entry = {"name": "floor_drift", "intervals": iv, "parameters_when_named": named}
    assert read_with_care({**entry, "se_when_named": {"drift_mm_s": [3.0, 3.0]}}) == [] and read_with_care(entry)


def test_a_named_effect_without_an_interval_is_said():
    """MRCLAM robot 4's whole log, the twin's recipe: heavy_tailed_noise named at its start (0.1, 2), EM having kept its
    start, and the final fit's information giving neither parameter an interval: the report says so, naming both;
    with every interval, nothing."""
    from types import SimpleNamespace

    from learners.discrepancy.effect_sizes import effect_intervals, without_interval
    from learners.model.heavy_tails import HeavyTailedNoise

    model = SimpleNamespace(effect=lambda name: HeavyTailedNoise(0.1, 2.0))
    iv = effect_intervals(model, "heavy_tailed_noise", {})  # no standard error: the information determines neither
    why = without_interval("heavy_tailed_noise", iv)
    assert why.startswith("heavy_tailed_noise: no 95% interval for rate 0.1, scale 2:") and "not a measured one" in why
    se = {"effects.heavy_tailed_noise.rate": 0.01, "effects.heavy_tailed_noise.scale": 0.2}
    assert without_interval("heavy_tailed_noise", effect_intervals(model, "heavy_tailed_noise", se)) == ""


def _scripted_search(monkeypatch, ctx, rounds, candidates, progress, refit=None):
    """``search`` of ``candidates`` on stand-ins: its base an empty model (``refit``: the base's refit with spurious
    sightings, as ``base_fits`` returns it; None: the base fitted the field), every fit and likelihood ``ctx``'s, every
    round ``rounds(trials, pool, jobs)``'s."""
    from learners.em.options import EMOptions

    monkeypatch.setattr(search_module, "base_fits", lambda logs, opts, action_model=None: (_Model(()), refit))
    monkeypatch.setattr(search_module, "outliers", lambda model, logs: np.zeros(0, dtype=bool))  # none set aside
    monkeypatch.setattr(search_module, "without", lambda logs, bad: logs)
    monkeypatch.setattr(search_module, "training_log", lambda tr: tr)
    monkeypatch.setattr(search_module, "applicable", lambda name, logs: True)
    monkeypatch.setattr(search_module, "SearchContext", lambda tr, logs, opts: ctx)
    monkeypatch.setattr(search_module, "with_null", lambda ctx, current, n: replace(ctx, current=current,
                                                                                  null_ll=ctx.loglik(current)))
    monkeypatch.setattr(search_module, "run_round", rounds)
    monkeypatch.setattr(search_module, "last_round_checks", lambda tried, ctx, pool: None)
    monkeypatch.setattr(search_module, "none_of_the_above", lambda *a: [])
    monkeypatch.setattr(search_module.MotionSide, "run", lambda self, ctx, c: Verdict("motion side", True, False))
    return search_module.search([], candidates, EMOptions(), jobs=1, progress=progress)


def test_a_base_in_a_wrong_world_gives_false_sightings_its_refit_as_a_second_start(monkeypatch):
    """The base ended in a wrong world and found the field with spurious sightings in the model (``base_fits``'
    refit): round 1 fits 'false_sightings' from that refit too (``fit_candidate``'s ``previous``) and no other
    candidate; an escape in round 1 keeps it for the repeated round (beside the escaped-from candidate's own fit);
    round 2, after 'false_sightings' is named, gives none; the search without it (``search_without``) from round 1
    has it again."""
    from types import SimpleNamespace

    s = frozenset
    train = {s(): -1100.0, s({"false_sightings"}): -900.0, s({"bias"}): -1090.0, s({"bias", "false_sightings"}): -895.0}
    refit = SimpleNamespace(params=_Model((_Effect("false_sightings"),)), info=SimpleNamespace(
        spurious_refit={"off_field_fraction": 0.91}))
    escaped = _Model(())
    seen = []

    def rounds(trials, pool, jobs=1):
        seen.append({t.name: t.previous for t in trials})
        out = []
        for t in trials:
            win = t.name == "false_sightings" and len(seen) > 1
            c = Candidate(t.name, {}, 100.0 if win else 0.0, 50.0, 1, 1e-12 if win else 1.0,
                          model=_Model(t.ctx.current.effects + (_Effect(t.name),)))
            c.checks.append(Verdict("likelihood ratio", win, escape=(escaped, -1000.0) if len(seen) == 1
                                    and t.name == "bias" else None))
            out.append(c)
        return out

    said = []
    out = _scripted_search(monkeypatch, _Context(train), rounds, ["false_sightings", "bias"], said.append, refit)
    assert [c.name for c in out["named"]] == ["false_sightings"] and len(out["escapes"]) == 1
    assert seen[0] == {"false_sightings": refit.params, "bias": None}
    assert seen[1]["false_sightings"] is refit.params and seen[1]["bias"].effects[-1].name == "bias"
    assert seen[2] == {"bias": None}
    assert out["base_refit"] == {"off_field_fraction": 0.91}
    assert any("wrong world (91% of the smoothed poses off the field)" in line for line in said)
    assert out["state"].starts[0].previous["false_sightings"] is refit.params


def test_an_effect_made_implausible_by_the_next_one_goes_before_the_next_round(monkeypatch):
    """Scripted rounds (stand-ins, MRCLAM robot 2's sequence): 'bias' named in round 1, 'lag' in round 2, whose refit
    leaves 'bias' implausible (a bias that holds 104 s). 'bias' is dropped at once, and round 3 runs on the model
    without it and names 'scale', which 'bias' had stood in for; before, it was dropped only after the last round."""

    s = frozenset
    train = {s(): -1100.0, s({"bias"}): -1000.0, s({"bias", "lag"}): -900.0, s({"lag"}): -950.0,
             s({"lag", "scale"}): -880.0, s({"scale"}): -1000.0}
    held = {s({"lag", "scale"}): -800.0, s({"lag"}): -850.0, s({"scale"}): -900.0}
    seen = []

    class Ctx(_Context):
        def fit(self, init, opts=None):  # the refit with 'lag' makes 'bias' implausible
            names = {e.name for e in init.effects}
            if names == {"bias", "lag"}:
                return _Model((_Effect("bias", why_implausible="tau_s 104 s is no pass-to-pass bias"), _Effect("lag")))
            return init

    def rounds(trials, pool, jobs=1):
        ctx = trials[0].ctx
        have = tuple(e.name for e in ctx.current.effects)
        seen.append(have)
        pick = {(): "bias", ("bias",): "lag", ("lag",): "scale"}.get(tuple(sorted(have)))
        out = []
        for t in trials:
            c = Candidate(t.name, {}, 50.0 if t.name == pick else 0.0, 10.0, 1, 1e-12 if t.name == pick else 1.0,
                          model=_Model(ctx.current.effects + (_Effect(t.name),)))
            c.checks.append(Verdict("likelihood ratio", t.name == pick))
            out.append(c)
        return out

    said = []
    out = _scripted_search(monkeypatch, Ctx(train, held), rounds, ["bias", "lag", "scale"], said.append)
    assert seen == [(), ("bias",), ("lag",)], seen
    assert [c.name for c in out["named"]] == ["lag", "scale"]
    assert "dropped: bias (given the others, tau_s 104 s is no pass-to-pass bias)" in said


def test_an_effect_the_final_fit_makes_implausible_is_dropped_and_the_search_run_again_without_it(monkeypatch):
    """The final fit on the whole logs takes 'bias' to values its class finds implausible (MRCLAM robot 4's first half:
    landmark_bias at 50 s when named, 459 s in the final fit): dropped, the search run again without it from the round
    that named it (its runner-up 'scale' named there), the final fit made again from that; only the fit kept gets its
    intervals; the time of both final fits counted."""
    from types import SimpleNamespace

    from learners.discrepancy import final as final_module
    from learners.discrepancy.final import FINAL_FIT_STAGE, Diagnosed, plausible_diagnosis

    calls, interval_calls, again = [], [], []

    def final_fit(found, opts, pool=None):
        calls.append(tuple(e.name for e in found["model"].effects))
        effects = tuple(_Effect(e.name, why_implausible="tau_s 459 s is no pass-to-pass bias" if e.name == "bias"
                                else "") for e in found["model"].effects)
        return SimpleNamespace(params=_Model(effects)), [{"start": "the search's model", "loglik": None, "kept": True}]

    def diagnosed(found, opts, final=None, pool=None):
        interval_calls.append(tuple(e.name for e in final.params.effects))
        return Diagnosed(final, [], [], {FINAL_FIT_STAGE: 10.0})

    def search_without(found, name, pool=None, progress=print):
        again.append(name)
        named = [c for c in found["named"] if c.name != name] + [Candidate("scale", {}, 0.0, 0.0, 1, 0.0)]
        return dict(found, named=named, model=_Model(tuple(_Effect(c.name) for c in named)),
                    winners=["lag", "scale"])

    monkeypatch.setattr(final_module, "final_fit", final_fit)
    monkeypatch.setattr(final_module, "diagnosed", diagnosed)
    monkeypatch.setattr(final_module, "search_without", search_without)
    named = [Candidate(n, {}, 0.0, 0.0, 1, 0.0) for n in ("lag", "bias")]
    found = {"named": named, "model": _Model((_Effect("lag"), _Effect("bias"))), "context": _Context({}),
             "winners": ["lag", "bias"],
             "learned": None}  # learn's model of the logs: made already (none here: the stand-in final fit needs none)
    said = []
    found2, final = plausible_diagnosis(found, None, said.append)
    assert again == ["bias"] and calls == [("lag", "bias"), ("lag", "scale")] and interval_calls == [("lag", "scale")]
    assert [c.name for c in found2["named"]] == ["lag", "scale"]
    assert found2["dropped_in_final"] == [{"name": "bias", "why": "tau_s 459 s is no pass-to-pass bias", "round": 2}]
    assert said == ["dropped: bias (in the final fit on the whole log(s), tau_s 459 s is no pass-to-pass bias)"]
    assert final.seconds[FINAL_FIT_STAGE] >= 10.0 and [c.name for c in found["named"]] == ["lag", "bias"]


def test_an_effect_the_final_fits_refit_makes_implausible_is_dropped_too(monkeypatch):
    """``diagnosed`` makes the final fit once more where a held fit of its intervals is more likely; that refit is
    what the report states, so it is checked as the first was (MRCLAM robot 4's whole log, the twin's recipe:
    landmark_bias plausible in the final fit, 72 s after the refit, above the 60 s bound, reported with a warning
    only). Here the refit takes 'bias' to 459 s: dropped, the search run again without it, the final fit made again
    and its intervals computed; the refit's intervals' time counted."""
    from types import SimpleNamespace

    from learners.discrepancy import final as final_module
    from learners.discrepancy.final import FINAL_FIT_STAGE, Diagnosed, plausible_diagnosis

    calls, interval_calls, again = [], [], []

    def final_fit(found, opts, pool=None):
        calls.append(tuple(e.name for e in found["model"].effects))
        return SimpleNamespace(params=found["model"]), [{"start": "the search's model", "loglik": None, "kept": True}]

    def diagnosed(found, opts, final=None, pool=None):  # the refit of a held fit: 'bias' at 459 s
        interval_calls.append(tuple(e.name for e in final.params.effects))
        refit = _Model(tuple(_Effect(e.name, why_implausible="tau_s 459 s is no pass-to-pass bias" if e.name == "bias"
                                     else "") for e in final.params.effects))
        return Diagnosed(SimpleNamespace(params=refit), [], [], {FINAL_FIT_STAGE: 10.0})

    def search_without(found, name, pool=None, progress=print):
        again.append(name)
        named = [c for c in found["named"] if c.name != name] + [Candidate("scale", {}, 0.0, 0.0, 1, 0.0)]
        return dict(found, named=named, model=_Model(tuple(_Effect(c.name) for c in named)), winners=["lag", "scale"])

    monkeypatch.setattr(final_module, "final_fit", final_fit)
    monkeypatch.setattr(final_module, "diagnosed", diagnosed)
    monkeypatch.setattr(final_module, "search_without", search_without)
    named = [Candidate(n, {}, 0.0, 0.0, 1, 0.0) for n in ("lag", "bias")]
    found = {"named": named, "model": _Model((_Effect("lag"), _Effect("bias"))), "context": _Context({}),
             "winners": ["lag", "bias"], "learned": None}
    said = []
    found2, final = plausible_diagnosis(found, None, said.append)
    assert calls == [("lag", "bias"), ("lag", "scale")] and again == ["bias"]
    assert interval_calls == [("lag", "bias"), ("lag", "scale")]
    assert [c.name for c in found2["named"]] == ["lag", "scale"]
    assert [e.name for e in final.result.params.effects] == ["lag", "scale"]
    assert found2["dropped_in_final"] == [{"name": "bias", "why": "tau_s 459 s is no pass-to-pass bias", "round": 2}]
    assert said == ["dropped: bias (in the final fit on the whole log(s), tau_s 459 s is no pass-to-pass bias)"]
    assert final.seconds[FINAL_FIT_STAGE] >= 20.0


def test_the_search_again_leaves_out_every_effect_the_final_fit_dropped(monkeypatch):
    """'c' named in round 2 was dropped in the final fit and the search run again from round 2 without it; the final fit
    then makes 'a', named in round 1, implausible: the search runs again from round 1, whose candidates held 'c' too,
    and leaves out both (else 'c', named and dropped, could be named again)."""
    from learners.discrepancy.search import RoundStart, SearchState, search_without

    seen = []
    monkeypatch.setattr(search_module, "run_rounds", lambda st, *args: seen.append(list(st.remaining)))
    monkeypatch.setattr(search_module, "finish", lambda st, *args: {"winners": st.winners})
    starts = [RoundStart(_Model(()), 0.0, [], ["a", "b", "c"], {}), RoundStart(_Model(()), 1.0, [], ["b", "c"], {})]
    found = {"state": SearchState(_Model(()), 2.0, ["b"], rounds=[[], []], winners=["a", "b"], starts=starts),
             "context": None, "max_rounds": 3, "dropped_in_final": [{"name": "c", "why": "", "round": 2}]}
    said = []
    search_without(found, "a", progress=said.append)
    assert seen == [["b"]] and said == ["the search again from round 1, without a, c"]
    search_without(dict(found, dropped_in_final=[]), "a", progress=said.append)
    assert seen[-1] == ["b", "c"] and said[-1] == "the search again from round 1, without a"


def test_the_drifting_size_warning_says_what_the_search_found_of_landmark_bias():
    """``aibo learn``'s warning ends "`aibo diagnose` ... tests landmark_bias"; in the diagnosis it says instead that
    the search dropped it (its own warning says why: not twice) or tried it and did not name it; untried, the advice
    stays."""
    from aibo.commands.diagnose import bias_tried
    from learners.em.support import TESTS_BIAS

    tried = {"rounds": [[Candidate("landmark_bias", {}, 0.0, 0.0, 2, 1.0)]], "dropped_in_final": []}
    assert "tried and not named" in bias_tried(tried)
    dropped = dict(tried, dropped_in_final=[{"name": "landmark_bias", "why": "tau_s 462 s is no pass-to-pass bias"}])
    assert bias_tried(dropped).endswith("dropped from the diagnosed model (its own warning says why)")
    assert bias_tried({"rounds": [[]]}) == TESTS_BIAS


def test_the_rounds_default_of_the_command_is_the_searchs():
    from aibo.cli import DIAGNOSE_ROUNDS
    from learners.discrepancy.search import MAX_ROUNDS

    assert DIAGNOSE_ROUNDS == MAX_ROUNDS


def test_the_replicas_default_of_the_command_is_the_checks():
    from aibo.cli import DIAGNOSE_REPLICAS
    from experiments.calibrated import REPLICAS

    assert DIAGNOSE_REPLICAS == REPLICAS


def _tried(name, round_, significant=True, gain=100.0):
    return {"name": name, "round": round_, "significant": significant, "gain_train": gain, "gain_heldout": gain,
            "p_value": 1e-20, "note": "the Fisher information overstates the data's by x4.14 (sandwich, 30 s blocks)"}


def test_why_a_significant_candidate_is_not_in_the_diagnosed_model():
    """MRCLAM robot 2 (whole log, defaults): distance_dependent_noise significant (held-out +397 nats) in the third
    and last round, which named beacon_height_scale; robot 3: landmark_bias named in round 3, dropped in the final fit.
    The reason given is the round's, not the test's note (a verdict it passed)."""
    from aibo.commands.diagnose import passed_over, round_limit

    rounds = {"max_rounds": 3, "winners": ["actuation_lag", "distance_dependent_noise", "beacon_height_scale"],
              "left_at_cap": ["floor_drift"],
              "dropped_in_final": [{"name": "landmark_bias", "why": "tau_s 734 s is no pass-to-pass bias", "round": 3}]}
    why = passed_over(_tried("floor_drift", 3), rounds)
    assert why.startswith("significant in round 3 (training gain 100.0 nats, p = 1e-20; held-out +100.0 nats) but not "
                          "named: beacon_height_scale had the larger held-out gain in that round; ")
    assert why.endswith("that round was the search's last (--rounds 3): --rounds 4 tries floor_drift again")
    assert passed_over(_tried("landmark_bias", 2), rounds) == (
        "named in round 3, then dropped from the diagnosed model: in the final fit, tau_s 734 s is no pass-to-pass bias; "
        "the search ran again from that round without it")
    assert passed_over(_tried("floor_drift", 2), rounds).endswith("distance_dependent_noise had the larger held-out "
                                                                 "gain in that round")  # not the last round
    assert passed_over(_tried("floor_drift", 3, significant=False), rounds) == ""  # its gains and note say why
    assert passed_over(_tried("floor_drift", 3), {}) == ""  # a report without the search's rounds
    robust = dict(_tried("floor_drift", 3), checks=[{"name": "robust likelihood ratio", "p": 4.2e-27}])
    assert "(training gain 100.0 nats, robust p = 4.2e-27; held-out" in passed_over(robust, rounds)
    (warning,) = round_limit(rounds, [_tried("floor_drift", 3), _tried("velocity_fade", 3, significant=False)])
    assert warning.startswith("the search stopped at its limit of 3 rounds with floor_drift (held-out +100.0 "
                              "nats, p = 1e-20) still significant") and warning.endswith("--rounds 4 tries it again")
    assert round_limit(dict(rounds, left_at_cap=[]), [_tried("floor_drift", 3)]) == []


def test_aibo_diagnose_says_which_candidates_its_last_round_left_significant(tmp_path, capsys):
    """Two effects in one simulated log, one round: the stronger is named, the other is reported left by the limit
    (report.json["search_rounds"], a warning, the printed line), not as refused."""
    import json

    from aibo.cli import main
    from aibo_core.trajectory import blind, save
    from aibo_gym.collect import collect

    tr = collect({"noise": "aibo", "effects": {"actuation_lag": {"lag_s": 0.2},
                                               "beacon_height_scale": {"scale": [1.08, 0.94, 1.04, 0.95]}}}, 9000, seed=3)
    save(blind(tr), tmp_path / "two.npz")
    out = tmp_path / "D"
    assert main(["diagnose", str(tmp_path / "two.npz"), "--out", str(out), "--candidates",
                 "actuation_lag,beacon_height_scale", "--jobs", "1", "--replicas", "0", "--rounds", "1"]) == 0
    text = capsys.readouterr().out
    report = json.loads((out / "report.json").read_text())
    assert [e["name"] for e in report["effects"]] == ["beacon_height_scale"]
    assert report["search_rounds"] == {"max_rounds": 1, "winners": ["beacon_height_scale"],
                                       "left_at_cap": ["actuation_lag"], "dropped_in_final": []}
    (lag,) = [c for c in report["candidates"] if c["name"] == "actuation_lag"]
    assert lag["significant"] and not lag["named"]
    assert any(w.startswith("the search stopped at its limit of 1 round with actuation_lag") for w in report["warnings"])
    assert "stopped: the search runs at most 1 round (--rounds), and actuation_lag was still significant" in text


def test_the_search_run_again_without_a_named_effect_names_what_a_search_without_that_candidate_names():
    """``search_without`` resumes from the state the round that named the effect started from (a better base model its
    escapes found kept: here one, from the left-out effect's own fit): it names what a search that never had the
    effect among its candidates names, and never tries the effect again. (Seed 4: the same rounds with OpenBLAS's
    kernels for this CPU and with its Haswell ones; seed 3, used before, named the lag and escaped twice with the
    first, and named nothing after the heights with the second.)"""
    from aibo_core.trajectory import blind
    from aibo_gym.collect import collect
    from learners.discrepancy.search import search, search_without
    from learners.em.options import EMOptions

    log = blind(collect({"noise": "aibo", "effects": {"actuation_lag": {"lag_s": 0.2},
                                                    "beacon_height_scale": {"scale": [1.08, 0.94, 1.04, 0.95]}}},
                        9000, seed=4))
    candidates = ["actuation_lag", "beacon_height_scale", "velocity_fade"]
    found = search([log], candidates, EMOptions(seed=0), jobs=1, progress=lambda s: None)
    assert found["winners"] == ["beacon_height_scale", "actuation_lag"]
    assert [(e["from"], e["round"]) for e in found["escapes"]] == [("actuation_lag", 2)]
    said = []
    again = search_without(found, "actuation_lag", progress=said.append)
    alone = search([log], ["beacon_height_scale", "velocity_fade"], EMOptions(seed=0), jobs=1, progress=lambda s: None)
    assert said[0] == "the search again from round 2, without actuation_lag"
    assert again["winners"] == alone["winners"] == ["beacon_height_scale"]
    assert [c.name for c in again["named"]] == [c.name for c in alone["named"]] == ["beacon_height_scale"]
    assert again["rounds"][0] is found["rounds"][0]  # round 1 as it was
    assert [c.name for c in again["rounds"][1]] == ["velocity_fade"]
    assert again["state"].starts[1][1] == found["state"].starts[1][1]  # from the state round 2 started from
    assert [e["from"] for e in again["escapes"]] == ["actuation_lag"]  # replayed, not tried again
    assert found["winners"] == ["beacon_height_scale", "actuation_lag"]  # the search it resumed is left as it was


@pytest.mark.parametrize("tau_s, refitted", [(0.4, False), (8.0, False), (150.0, True)])
def test_the_staged_refit_is_for_a_ridge_not_for_the_white_noise_limit(monkeypatch, tau_s, refitted):
    """``fit_candidate`` fits an implausible fit again in stages only where it may have climbed a ridge
    (``EffectModel.ridge_possible``): a bias that holds for 150 s may (seed 2001's direct fit, rescued by the staged
    one: ``tests/test_landmark_bias.py``); one gone within a second is the model's white-noise limit, to which the
    staged refit returned on 9 of 9 effect-free logs, so it is not refitted; a plausible fit never is."""
    from learners.model.landmark_bias import MIN_PLAUSIBLE_TAU_S

    bias = LandmarkBias(0.01, tau_s)
    assert bias.ridge_possible() == (tau_s >= MIN_PLAUSIBLE_TAU_S)
    start = _Model((_Effect("landmark_bias"),))
    fitted = _Model((bias,))
    calls = []
    monkeypatch.setattr(search_module, "candidate_start", lambda name, ctx: start)
    monkeypatch.setattr(search_module, "staged", lambda *a: calls.append(a) or (a[2], a[3]))
    monkeypatch.setattr(search_module, "tested", lambda name, model, ll, ctx: Candidate(name, {}, 0.0, 0.0, 2, 1.0))
    ctx = _Context(train_ll={frozenset({"landmark_bias"}): -10.0})
    ctx.fit = lambda init, opts=None: fitted
    search_module.fit_candidate("landmark_bias", ctx)
    assert bool(calls) == refitted
