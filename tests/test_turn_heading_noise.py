"""``turn_heading_noise``: the heading's noise grows with the turn rate, its standard deviation x sqrt(1 + (gain_s
omega)^2), the forward and lateral noise unchanged (the learner's twin ``learners.model.turn_noise.TurnHeadingNoise``,
a per-frame factor in ``Lowered.cov_sd``, and the simulator's ``aibo_gym.catalogue.TurnHeadingNoise``, whose test is
tests/test_turn_dependent_noise.py's, with that effect's twin)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aibo_core.trajectory import blind
from aibo_gym.collect import collect
from aibo_gym.config import default_config
from learners.arrays.batch import make_batch
from learners.arrays.displacement import pose_displacement_beliefs
from learners.em.estep import e_step
from learners.em.learner import EMLearner
from learners.em.options import EMOptions
from learners.inference.action_stats import action_statistics
from learners.model.turn_noise import TurnHeadingNoise
from tests.test_mrclam import needs_data
from tests.test_turn_dependent_noise import real_robot_fits

GAIN = TurnHeadingNoise.EXAMPLE["gain_s"]
OPTS = EMOptions(starts=1, alias_search=False, lag_search=False)  # one start, no searches: the effect's own fit


def _log(gain: float, seed: int, minutes: float = 5.0):
    effects = {"turn_heading_noise": {"gain_s": gain}} if gain else {}
    return blind(collect({"noise": "aibo", "effects": effects}, int(minutes * 1800), seed=seed))


def _base(tr, max_iter: int | None = None):
    opts = OPTS if max_iter is None else EMOptions(starts=1, max_iter=max_iter, alias_search=False, lag_search=False)
    return EMLearner(opts).fit([tr]).params


def test_the_model_scales_each_frames_heading_noise_by_its_commanded_turn():
    """cov_sd's heading column is sqrt(1 + (g omega)^2) and the others 1; Sigma_i = D_i Sigma_A D_i
    (``Lowered.frame_cov``): the heading variance x (1 + (g omega)^2), the position block as Sigma_A's."""
    tr = _log(0.0, seed=3, minutes=0.5)
    batch = make_batch([tr])
    base = _base(tr, max_iter=3)
    lo0 = base.lower(batch)
    lo = base.with_effect(TurnHeadingNoise(2.0)).lower(batch)
    omega = lo0.disp[:, 2] / batch.dt
    assert np.ptp(omega) > 1.0  # the log turns at several rates
    np.testing.assert_allclose(lo.cov_sd[:, 2], np.sqrt(1.0 + (2.0 * omega) ** 2), rtol=1e-12)
    np.testing.assert_array_equal(lo.cov_sd[:, :2], 1.0)
    np.testing.assert_array_equal(lo.cov_scale, lo0.cov_scale)
    S = lo.frame_cov()
    np.testing.assert_allclose(S[:, 2, 2], base.action.cov[2, 2] * (1.0 + (2.0 * omega) ** 2), rtol=1e-12)
    np.testing.assert_allclose(S[:, :2, :2], np.broadcast_to(base.action.cov[:2, :2], (len(S), 2, 2)), rtol=1e-12)


def test_the_per_frame_beliefs_whitened_sum_to_the_action_statistics():
    """The action M-step's ``C_sum`` is sum_i D_i^-1 C*_i D_i^-1 / cov_scale_i of the per-frame beliefs, with a
    factor that varies across frames."""
    tr = _log(GAIN, seed=3, minutes=0.5)
    batch = make_batch([tr])
    model = _base(tr, max_iter=5).with_effect(TurnHeadingNoise(GAIN))
    lo = model.lower(batch)
    post = e_step(model, batch, "numpy")
    mu, C = pose_displacement_beliefs(lo, batch, post)
    mu_star, C_sum = action_statistics(lo, batch, post, need_cov=True)
    np.testing.assert_allclose(mu, mu_star, rtol=1e-12)
    d = lo.cov_sd
    np.testing.assert_allclose((C / (d[:, :, None] * d[:, None, :])).sum(axis=0), C_sum, rtol=1e-12)
    assert not np.allclose(C.sum(axis=0), C_sum)  # the factors matter


@pytest.mark.parametrize("seed", [5, 6])
def test_em_recovers_the_gain_and_the_straight_line_heading_noise(seed):
    """5-minute ``aibo`` logs with gain 1.5 s/rad: measured 1.50 / 1.45 (seeds 5 / 6), the heading's noise 0.0200 /
    0.0192 rad (truth 0.02); the base model without the effect takes 0.038 / 0.032. (Seed 4 ends at 0.82 with 0.031
    rad, from a start at the truth too: the likelihood's maximum there, the baseline and the gain trading along a
    ridge.)"""
    tr = _log(GAIN, seed)
    base = _base(tr)
    model = EMLearner(OPTS).fit([tr], init=base.with_effect(TurnHeadingNoise.start(make_batch([tr])))).params
    assert abs(model.effect("turn_heading_noise").gain_s - GAIN) < 0.25 * GAIN
    truth = default_config()["slip_std"][2]  # the simulator's heading slip (rad per frame)
    assert abs(math.sqrt(model.action.cov[2, 2]) - truth) < 0.1 * truth
    assert math.sqrt(base.action.cov[2, 2]) > 1.3 * truth  # without it the straight-line noise is taken too wide


def test_an_effect_free_log_keeps_the_gain_near_zero():
    tr = _log(0.0, seed=5)
    model = EMLearner(OPTS).fit([tr], init=_base(tr).with_effect(TurnHeadingNoise.start(make_batch([tr])))).params
    assert model.effect("turn_heading_noise").gain_s < 0.3


@pytest.mark.realdata
@needs_data
def test_on_a_real_robot_it_predicts_the_unseen_sightings_better_and_keeps_the_straight_line_noise():
    """MRCLAM robot 1, its first 10 minutes (data our simulator did not shape), outliers set aside as ``aibo diagnose``
    does: fitted on the training half from ``aibo learn``'s model, the effect takes a gain of tens of s/rad, predicts
    the held-out sightings better than the same model refitted the same way without it, and keeps the forward noise
    of the model without it (``turn_dependent_noise`` shrinks it to a third: what Vicon says it is not). Measured
    2026-11-28: 31.6 s/rad, held-out +148 nats, forward sd 3.39 mm against the null's 3.28 (``turn_dependent_noise``:
    1.25); robots 2-5: 20.7-36.2 s/rad, +109 to +293 nats (docs/results.md, "The heading's noise alone grows with the
    turn")."""
    null, model, heldout = real_robot_fits(TurnHeadingNoise)
    assert model.effect("turn_heading_noise").gain_s > 5.0 and heldout > 20.0, heldout
    assert math.sqrt(model.action.cov[0, 0]) > 0.8 * math.sqrt(null.action.cov[0, 0])
