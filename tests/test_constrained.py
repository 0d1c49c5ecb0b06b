"""Constrained parameters: a normalized group (``Param(transform="logcontrast")``, e.g. the per-landmark
factors of ``beacon_height_scale`` at geometric mean 1) is packed as the contrasts of its logs, so the
packed vector SQUAREM extrapolates and the Fisher information is taken over has no direction the
normalization removed (docs/em-math.md, "Standard errors")."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from aibo_gym.collect import collect
from learners.arrays.batch import make_batch
from learners.em.finish import fisher_scoring
from learners.em.learner import EMLearner
from learners.em.options import EMOptions
from learners.em.uncertainty import parameter_uncertainty
from learners.model.effects import BeaconHeightScale
from learners.model.model import paper_start
from learners.model.parameters import Param, helmert, pack_logcontrast, unpack_logcontrast
from tests._logs import sim_log

TRUE_SCALE = np.array([1.08, 0.94, 1.04, 0.95])
NORMALIZED = TRUE_SCALE / np.exp(np.mean(np.log(TRUE_SCALE)))


def test_helmert_basis_is_orthonormal_and_orthogonal_to_the_common_factor():
    H = helmert(4)
    assert H.shape == (4, 3)
    np.testing.assert_allclose(H.T @ H, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(H.sum(axis=0), 0.0, atol=1e-15)
    np.testing.assert_allclose(H @ H.T, np.eye(4) - 0.25, atol=1e-15)  # the projection that removes the mean
    np.testing.assert_allclose(H[:, 0], [1 / math.sqrt(2), -1 / math.sqrt(2), 0, 0])
    assert helmert(1).shape == (1, 0)


def test_a_normalized_group_round_trips_through_its_contrasts():
    """Known case: (2, 1/2, 1, 1) has log contrasts (sqrt(2) log 2, 0, 0), and comes back exactly."""
    value = np.array([2.0, 0.5, 1.0, 1.0])
    x = pack_logcontrast(value)
    np.testing.assert_allclose(x, [math.sqrt(2) * math.log(2), 0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(unpack_logcontrast(x, np.ones(4)), value, rtol=1e-14)
    # any packed vector unpacks to geometric mean 1 (a normalized old value) ...
    anything = unpack_logcontrast(np.array([0.3, -1.2, 0.7]), value)
    assert np.exp(np.mean(np.log(anything))) == pytest.approx(1.0, abs=1e-14)
    # ... and a group that is not normalized keeps its common factor (the model's predictions are kept)
    off = 3.0 * value
    np.testing.assert_allclose(unpack_logcontrast(pack_logcontrast(off), off), off, rtol=1e-14)


def test_the_packed_model_has_one_entry_fewer_and_the_effect_one_degree_of_freedom_fewer():
    tr = sim_log(600)
    model = paper_start([tr]).with_effect(BeaconHeightScale(NORMALIZED))
    layout = dict(((c, p), n) for c, p, n in model.packed_layout())
    assert layout[("effects.beacon_height_scale", "scale")] == 3
    assert model.effects[0].dof() == 3
    back = model.unpack(model.pack() + 0.1)  # a move of every packed coordinate
    assert np.exp(np.mean(np.log(back.effects[0].scale))) == pytest.approx(1.0, abs=1e-14)
    assert Param("", "logcontrast").constraints == 1 and Param("", "log").constraints == 0
    assert "must be > 0" in Param("", "logcontrast").domain_error(np.array([1.0, -1.0]))


def _scale_fit(seed: int, steps: int = 9000):
    """EM with ``beacon_height_scale`` on a simulated log with per-beacon heights TRUE_SCALE (aibo noise),
    from the true velocities (every fit in the right basin)."""
    tr = collect({"noise": "aibo", "robot_seed": 3, "max_steps": steps,
                  "effects": {"beacon_height_scale": {"scale": TRUE_SCALE.tolist()}}}, steps=steps, seed=seed)
    start = paper_start([tr])
    start = start.with_(action=start.action.with_values(weights=np.array(tr.truth["velocities"]) * tr.dt))
    return EMLearner(EMOptions(starts=1, patience=20)).fit([tr], init=start.with_effect(BeaconHeightScale(np.ones(4)))), tr


def test_a_fit_with_a_normalized_group_has_a_regular_information_and_true_standard_errors():
    """Before the transform the information was singular (condition number ~1e12, the scales' standard
    errors ~500 and the curve's ~1e8, the Newton decrement ~500 along the removed direction)."""
    res, tr = _scale_fit(703)
    info, se = res.info["information"], res.info["standard_errors"]
    assert info["condition_number"] < 1e3, info
    assert info["newton_decrement"] < 20, info
    assert not any(n.startswith("effects.beacon_height_scale.scale[") for n in res.info["information"]["undetermined"])
    scale_se = np.array(se["effects.beacon_height_scale.scale"], dtype=float)
    assert np.all((scale_se > 1e-3) & (scale_se < 0.01)), scale_se  # ~0.0035 on 5 minutes
    est = res.params.effect("beacon_height_scale").scale
    assert np.exp(np.mean(np.log(est))) == pytest.approx(1.0, abs=1e-12)
    assert np.all(np.abs(est - NORMALIZED) < 4 * scale_se), (est, scale_se)
    # the curve's standard errors: as if the scales were known, up to what estimating 3 contrasts adds
    # (before: 1e3-1e4 times larger, the common factor shared between the curve and the scales)
    known = parameter_uncertainty(res.params, make_batch([tr]), frozenset({"effects.beacon_height_scale.scale"}))
    ratio = np.array(se["sensor_model.coef"], dtype=float) / np.array(known.standard_errors["sensor_model.coef"], dtype=float)
    assert np.all((ratio >= 0.99) & (ratio < 3.0)), ratio
    assert not [w for w in res.info["warnings"] if w.startswith("weakly determined")], res.info["warnings"]


@pytest.mark.slow
def test_the_scale_standard_errors_match_the_spread_over_simulated_logs():
    """8 independent 5-minute logs: per landmark, the RMS reported standard error is within a factor 1.5 of
    the empirical standard deviation of the estimates (measured: ratios 0.87-1.43), and the estimates are
    centred on the normalized truth."""
    est, se = [], []
    for i in range(8):
        res, _ = _scale_fit(700 + i)
        est.append(res.params.effect("beacon_height_scale").scale)
        se.append(np.array(res.info["standard_errors"]["effects.beacon_height_scale.scale"], dtype=float))
    est, se = np.array(est), np.array(se)
    ratio = np.sqrt(np.mean(se**2, axis=0)) / est.std(axis=0, ddof=1)
    assert np.all((ratio > 1 / 1.5) & (ratio < 1.5)), ratio
    assert np.all(np.abs(est.mean(axis=0) - NORMALIZED) < 3 * se.mean(axis=0) / np.sqrt(len(est))), est.mean(axis=0)


def test_an_extrapolated_step_outside_a_domain_is_projected_back_onto_it():
    """SQUAREM's extrapolation once took distance_dependent_noise's exponent (domain [0, 10]) to -0.56, named in a
    model file that could not be loaded: unpacking clips every scaled or log parameter to its domain."""
    from learners.model.catalogue import DistanceDependentNoise
    from learners.model.catalogue_more import FalseSightings

    noise = DistanceDependentNoise(exponent=0.5)
    assert noise.unpack_param("exponent", np.array([-5.6]))[0] == 0.0
    assert noise.unpack_param("exponent", np.array([3.0]))[0] == pytest.approx(0.3)
    fs = FalseSightings(0.1)  # a log parameter with a domain: (0, 0.5]
    assert fs.unpack_param("rate", np.array([math.log(0.9)]))[0] == 0.5
    assert fs.unpack_param("rate", np.array([math.log(0.2)]))[0] == pytest.approx(0.2)


UNICYCLE_HELD = ["action_model.weights[0][1]", "action_model.weights[1][0]", "action_model.weights[1][1]",
                 "action_model.weights[2][1]", "action_model.weights[3][0]", "action_model.weights[3][1]",
                 "action_model.weights[4][0]", "action_model.weights[4][1]", "action_model.weights[4][2]"]


def test_weights_the_unicycle_holds_at_zero_are_reported_as_fixed_not_estimated():
    """``unicycle`` holds its lateral weights, its forward speed's omega, |omega| and constant terms and its turn rate's
    constant at exactly 0
    (``ZERO_OUTPUTS``, ``ZERO_CELLS``). They are no parameters: before, the information took them as free (26
    parameters, the weakest direction made of lateral weights, a standard error for each, the forward weights'
    errors inflated by them) and the scoring finish moved them off 0. Now: listed as ``fixed`` (not
    ``undetermined``), standard error exactly 0.0, kept at 0 by the finish, and printed as fixed."""
    from aibo.commands.learn import uncertainty_report
    from tests._diffdrive import diff_drive_log

    tr = diff_drive_log(120.0, seed=0)
    # the curve held (a 2-minute log's sightings leave the free curve's far node undetermined: not this test's matter)
    res = EMLearner(EMOptions(finish="scoring", range_curve="held")).fit([tr], action_model="unicycle")
    w, info = res.params.action.weights, res.info["information"]
    held = np.zeros((5, 3), dtype=bool)
    held[:, 1], held[[1, 3, 4], 0], held[4, 2] = True, True, True  # ZERO_OUTPUTS: dy; ZERO_CELLS: in dx, in dtheta
    np.testing.assert_array_equal(res.params.action.zero_cells(), held)
    assert np.all(w[held] == 0.0), w  # the finish did not move them
    assert info["fixed"] == UNICYCLE_HELD
    # 6 free weights, 3 curve nodes + 2 sigmas + 6 log-Cholesky, the range's shrink k (EMOptions.range_shrink)
    assert info["parameters"] == 15 - 9 + 12
    assert not set(UNICYCLE_HELD) & set(info["undetermined"] + info["weakest_direction"]), info
    se = np.array(res.info["standard_errors"]["action_model.weights"], dtype=float)
    assert np.all(se[held] == 0.0) and np.all(np.isfinite(se)) and np.all(se[~held] > 0), se
    lines = uncertainty_report(res)
    assert any(line.startswith("  fixed by the model") and "action_model.weights[0][1]" in line for line in lines)
    assert not any("undetermined" in line for line in lines), lines


def test_a_landmark_never_sighted_leaves_its_height_scale_undetermined_and_the_others_as_without_it():
    """Landmark 3's sightings dropped from the log: no sighting depends on its height scale, and through the
    normalization (geometric mean 1) and the sensor curve (which absorbs the common factor) the information is
    singular along its contrast direction (before: condition number ~5e12, the scales' standard errors ~1000, the
    curve's ~1e5, nothing named undetermined, the Newton decrement ~480). Its scale is now undetermined, like a
    command never executed: kept at its start (1) by EM, error None, listed; every other error is the one given
    it held, which is that of the same model on the same sightings without landmark 3 at all. With the curve held
    the normalization alone determines it: then it is reported like any parameter."""

    steps = 6000
    tr = collect({"noise": "aibo", "robot_seed": 3, "max_steps": steps,
                  "effects": {"beacon_height_scale": {"scale": TRUE_SCALE.tolist()}}}, steps=steps, seed=703)
    keep = tr.sighting_landmark != 3
    tr = replace(tr, sighting_frame=tr.sighting_frame[keep], sighting_landmark=tr.sighting_landmark[keep],
                 sighting_value=tr.sighting_value[keep])
    start = paper_start([tr])
    start = start.with_(action=start.action.with_values(weights=np.array(tr.truth["velocities"]) * tr.dt))
    res = EMLearner(EMOptions(starts=1, patience=20)).fit([tr], init=start.with_effect(BeaconHeightScale(np.ones(4))))
    info, se = res.info["information"], res.info["standard_errors"]
    assert info["undetermined"] == ["effects.beacon_height_scale.scale[3]"], info
    assert res.info["undetermined"] == ["effects.beacon_height_scale.scale[3]"]  # the fit's own list and warning
    assert any("effects.beacon_height_scale.scale[3]): kept at their start" in w for w in res.info["warnings"])
    assert info["condition_number"] < 1e5 and info["newton_decrement"] < 20, info
    scale = res.params.effect("beacon_height_scale").scale
    assert scale[3] == pytest.approx(1.0, abs=1e-9) and np.exp(np.mean(np.log(scale[:3]))) == pytest.approx(1.0, abs=1e-12)
    scale_se = se["effects.beacon_height_scale.scale"]
    assert scale_se[3] is None and all(0.001 < s < 0.02 for s in scale_se[:3]), scale_se
    assert np.all(np.abs(scale[:3] - TRUE_SCALE[:3] / np.exp(np.mean(np.log(TRUE_SCALE[:3])))) < 4 * np.array(scale_se[:3]))

    # the same model and sightings with landmark 3 removed: the same standard errors (central differences)
    model, batch = res.params, make_batch([tr])
    three = replace(tr, landmarks=tr.landmarks[:3])
    model3 = model.with_effect(BeaconHeightScale(scale[:3]))
    four = parameter_uncertainty(model, batch, step=-1e-5)
    ref = parameter_uncertainty(model3, make_batch([three]), step=-1e-5)
    assert four.undetermined == ["effects.beacon_height_scale.scale[3]"] and not ref.undetermined
    assert four.summary()["parameters"] == len(ref.names)
    assert four.condition_number == pytest.approx(ref.condition_number, rel=1e-3)
    assert four.newton_decrement == pytest.approx(ref.newton_decrement, rel=1e-3, abs=1e-3)
    for key, want in ref.standard_errors.items():
        got = np.array(four.standard_errors[key], dtype=float)
        got = got[:3] if key == "effects.beacon_height_scale.scale" else got
        np.testing.assert_allclose(got, np.array(want, dtype=float), rtol=1e-6, err_msg=key)  # measured: 4e-12

    # the scoring finish steps along the directions the data determine: the unseen scale stays at 1
    done = fisher_scoring(model, batch, max_steps=1)
    assert done.record["steps"] and done.model.effect("beacon_height_scale").scale[3] == pytest.approx(1.0, abs=1e-9)

    # the curve held: the normalization determines the unseen scale (1 / the others' product)
    held = parameter_uncertainty(model, batch, frozenset({"sensor.coef"}))
    assert not held.undetermined and all(s > 0 for s in held.standard_errors["effects.beacon_height_scale.scale"])


def test_the_height_scales_m_step_is_the_constrained_maximum():
    """``geometric_mean_one``: the factors maximizing sum_b (2 num_b s_b - den_b s_b^2) at a given product. When the
    unconstrained optimum num / den already has that product it is returned as is; otherwise the product holds to
    rounding and no other factors with the same product (moved along random contrasts) do better."""
    from learners.model.effects import geometric_mean_one

    rng = np.random.default_rng(4)
    den = rng.uniform(1.0, 50.0, 6)
    free = np.array([1.1, 0.9, 1.05, 0.97, 1.2, 1.0])
    free /= np.exp(np.mean(np.log(free)))
    np.testing.assert_allclose(geometric_mean_one(free * den, den, 0.0), free, rtol=1e-12)

    num = den * free * 1.07  # a common factor 1.07 the constraint must take out, unequally (den differs)
    s = geometric_mean_one(num, den, 0.0)
    assert np.sum(np.log(s)) == pytest.approx(0.0, abs=1e-12)

    def objective(x):
        return float(np.sum(2 * num * x - den * x * x))

    H = helmert(6)
    for _ in range(200):
        other = s * np.exp(H @ rng.normal(0, 0.02, 5))  # H (6, 5): the contrasts, orthogonal to the common factor
        assert np.sum(np.log(other)) == pytest.approx(0.0, abs=1e-9)
        assert objective(other) <= objective(s) + 1e-9
    assert not np.allclose(s, num / den / np.exp(np.mean(np.log(num / den))))  # not the plain normalization


def test_a_range_curve_held_at_the_distance_stays_held_with_height_scales():
    """A wheeled log (range sensor, 8 landmarks) with per-landmark range factors at geometric mean 1: ``aibo
    learn --range-curve held``'s fit of a range sensor holds the curve at range = distance (``EMOptions.range_curve``), and with
    ``beacon_height_scale`` it stays exactly there; the factors come back. (The effect's M-step used to move the
    unconstrained factors' common factor into the curve: on MRCLAM robot 4's first half the held curve drifted to
    1.069 x distance, and the forward speed with it.)"""
    from aibo_gym.collect_wheeled import collect_wheeled

    true = np.array([1.04, 0.97, 1.02, 0.96, 1.03, 0.99, 1.01, 0.985])
    true /= np.exp(np.mean(np.log(true)))
    tr = collect_wheeled({"effects": {"beacon_height_scale": {"scale": true.tolist()}}}, 3000, seed=5)
    held = EMOptions(seed=0, range_curve="held")
    plain = EMLearner(held).fit([tr], action_model="unicycle")
    start = plain.params.with_effect(BeaconHeightScale(np.ones(len(true))))
    res = EMLearner(held).fit([tr], init=start)
    np.testing.assert_array_equal(res.params.sensor.coef, plain.params.sensor.coef)
    assert list(plain.params.sensor.coef[:2]) == [0.0, 1.0]
    scale = res.params.effect("beacon_height_scale").scale
    se = np.array(res.info["standard_errors"]["effects.beacon_height_scale.scale"], dtype=float)
    assert np.sum(np.log(scale)) == pytest.approx(0.0, abs=1e-9)
    assert np.all(np.abs(scale - true) < 4 * se) and np.all(se < 0.01), (scale, se)
