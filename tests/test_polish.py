"""The polish after EM (``EMOptions.polish``, ``EffectModel.polish``): ECME's conditional step on the likelihood itself,
here ``landmark_bias``' (sigma_rel, tau_s), whose EM update crawls along a ridge of the likelihood."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from aibo_core.trajectory import blind
from aibo_gym.collect import collect
from learners.arrays.batch import make_batch
from learners.em import checkpoint
from learners.em.estep import forward_loglik
from learners.em.fit import POLISH_ROUNDS, initial_state, run
from learners.em.learner import EMLearner
from learners.em.options import EMOptions
from learners.model.landmark_bias import LandmarkBias

TRUTH = {"sigma_rel": 0.05, "tau_s": 8.0}
WARM = EMOptions(starts=1, uncertainty=False, alias_search=False, lag_search=False)


def _bias_log(steps: int, seed: int):
    return blind(collect({"noise": "aibo", "effects": {"landmark_bias": TRUTH}}, steps, seed=seed))


@pytest.fixture(scope="module")
def fitted():
    """A 2-minute blind log with bias states and its base model (no effect)."""
    tr = _bias_log(3600, 7)
    return tr, EMLearner(WARM, check_field=False).fit([tr]).params


def test_polish_ends_at_the_likelihoods_maximum_over_its_parameters_with_the_rest_held(fitted):
    tr, base = fitted
    batch = make_batch([tr])
    loglik = forward_loglik(batch)
    start = base.with_effect(LandmarkBias(0.02, 30.0))  # far along the ridge EM crawls on
    e = start.effect("landmark_bias").polish(start, batch, loglik)
    top = loglik(start.with_effect(e))
    assert top > loglik(start) + 1.0
    for d_sigma, d_tau in [(0.05, 0.0), (-0.05, 0.0), (0.0, 0.1), (0.0, -0.1), (0.05, 0.1), (-0.05, -0.1)]:
        nearby = LandmarkBias(e.sigma_rel * math.exp(d_sigma), e.tau_s * math.exp(d_tau))
        assert loglik(start.with_effect(nearby)) <= top + 0.02, (d_sigma, d_tau)


def test_an_effect_without_a_polish_is_left_as_it_is(fitted):
    tr, base = fitted
    from learners.model.effects import EFFECT_MODELS

    drift = EFFECT_MODELS["floor_drift"].start(make_batch([tr]))
    assert drift.polish(base.with_effect(drift), make_batch([tr]), forward_loglik(make_batch([tr]))) is drift


def test_em_with_the_polish_ends_more_likely_and_counts_its_steps(fitted):
    """From the same warm start, the fit that polishes after convergence (EM resumed after each step) ends more likely
    than EM alone, with at most POLISH_ROUNDS steps; without the option none is taken."""
    tr, base = fitted
    batch = make_batch([tr])
    start = base.with_effect(LandmarkBias(0.02, 30.0))
    opts = replace(WARM.comparable(), patience=15, gate=None)
    plain = run(batch, initial_state(start, batch, opts), opts)
    polished = run(batch, initial_state(start, batch, replace(opts, polish=True)), replace(opts, polish=True))
    assert plain.polishes == 0 and 1 <= polished.polishes <= POLISH_ROUNDS
    assert polished.best_loglik > plain.best_loglik + 0.5


def test_a_checkpoint_keeps_the_polish_steps_taken(tmp_path, fitted):
    tr, base = fitted
    batch = make_batch([tr])
    state = initial_state(base, batch, WARM)
    state.polishes = 3
    checkpoint.save(tmp_path / "c.npz", state, "fp")
    assert checkpoint.load(tmp_path / "c.npz", "fp").polishes == 3


@pytest.mark.slow
def test_with_the_final_fits_stop_rule_the_polish_shortens_the_correlation_time_em_leaves_long():
    """The calibration study's log 4 (seed 8004, 5 minutes, tau_s 8 s), from the value a candidate is typically named
    at (0.035, 25 s) with the final fit's stop rule (0.1 nat within 15 iterations): EM alone stopped at 14.3 s, the
    polished fit at 12.4 s and more likely (its whole-log fit in the study: 15.7 s before the polish, 11.9 s after)."""
    tr = blind(collect({"noise": "aibo", "effects": {"landmark_bias": TRUTH}}, 9000, seed=8004))
    base = EMLearner(EMOptions(uncertainty=False), check_field=False).fit([tr]).params
    start = base.with_effect(LandmarkBias(0.035, 25.0))
    opts = replace(EMOptions(uncertainty=False).comparable(), patience=15, alias_search=False, starts=1)
    early = EMLearner(opts, check_field=False).fit([tr], init=start)
    polished = EMLearner(replace(opts, polish=True), check_field=False).fit([tr], init=start)
    tau_early, tau = early.params.effect("landmark_bias").tau_s, polished.params.effect("landmark_bias").tau_s
    assert tau_early > 13.0 and tau < tau_early - 1.0
    assert max(polished.loglik) > max(early.loglik)


def test_the_lag_is_refined_below_its_grid():
    """A simulated wheeled robot whose commands act 0.25 s late (between the grid's 0.2 and 0.3, where the search
    places it): from 0.2 s, EM with the polish ends within 20 ms of 0.25 s, and more likely."""
    from aibo_gym.collect_wheeled import collect_wheeled
    from learners.model.catalogue import ActuationLag

    tr = collect_wheeled({"effects": {"actuation_lag": {"lag_s": 0.25}}, "start_pose": "random"}, 6000, 3)
    opts = replace(EMOptions(uncertainty=False, lag_search=False).comparable(), patience=15, alias_search=False)
    start = EMLearner(opts, check_field=False).fit([tr]).params.with_effect(ActuationLag(0.2))
    held = EMLearner(opts, check_field=False).fit([tr], init=start)
    polished = EMLearner(replace(opts, polish=True), check_field=False).fit([tr], init=start)
    assert held.params.effect("actuation_lag").lag_s == 0.2  # EM alone does not move it (no M-step: a grid parameter)
    assert abs(polished.params.effect("actuation_lag").lag_s - 0.25) < 0.02
    assert max(polished.loglik) > max(held.loglik)


def test_a_discrete_commands_lag_is_polished_in_whole_frames(fitted):
    """Aibo commands move by whole frames: the polished lag is a whole number of frames."""
    from learners.model.catalogue import ActuationLag

    tr, base = fitted
    batch = make_batch([tr])
    lag = ActuationLag(0.1).polish(base.with_effect(ActuationLag(0.1)), batch, forward_loglik(batch))
    frames = lag.lag_s / tr.dt
    assert 0.0 <= lag.lag_s <= 0.2 and abs(frames - round(frames)) < 1e-9
