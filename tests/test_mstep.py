"""Tests of the action and sensor M-steps (learners.em.action_mstep, learners.em.sensor_mstep)."""

from __future__ import annotations

import numpy as np
import pytest

from learners.em import action_mstep as am
from aibo_core import geometry as geo
from learners.em import sensor_mstep as sms
from learners.em.data import Batch
from learners.em.params import ActionModel, InitialState, Params, SensorModel
from learners.em.posterior import Posterior
from learners.em.smoother import smooth

DT = 1.0 / 30.0
STD = np.array([5.0, 5.0, 0.03])
BEACONS = np.array([[-2700.0, -1800.0], [2700.0, -1800.0], [-2700.0, 1800.0], [2700.0, 1800.0]])
PINHOLE = lambda d: 57000.0 / d  # noqa: E731


def pinhole_cubic(sh=1.5, sa=0.05) -> SensorModel:
    d = np.linspace(1000.0, 4500.0, 200)
    return SensorModel(np.polynomial.Polynomial.fit(d, PINHOLE(d), 3).convert().coef, sh, sa)


def simulate(rng, T, vel, seg=30, p_seen=0.6, sensor=None, height=None):
    """Random trajectory: (actions, obs, beacon_xy, seen, true poses). ``height(d)`` overrides f."""
    sensor = sensor or pinhole_cubic()
    actions = np.repeat(rng.integers(0, len(vel), T // seg + 1), seg)[:T].astype(np.int64)
    pose = np.zeros((T + 1, 3))
    noise = rng.standard_normal((T, 3)) * STD
    for i in range(T):
        pose[i + 1] = geo.motion(pose[i], vel[actions[i]] * DT + noise[i])[0]
    b = rng.integers(0, len(BEACONS), T)
    h, _, d = geo.observe(pose[1:], BEACONS[b], sensor)
    seen = (rng.random(T) < p_seen) & (d >= 1275.0) & (d <= 4175.0)  # the recognizable range
    if height is not None:
        h[:, 0] = height(d)
    obs = h + rng.standard_normal((T, 2)) * [sensor.sigma_height, sensor.sigma_angle]
    obs[:, 1] = geo.wrap(obs[:, 1])
    obs[~seen] = np.nan
    return actions, obs, np.where(seen[:, None], BEACONS[b], np.nan), seen, pose


def batch_of(log) -> Batch:
    return Batch(log[0], log[1], log[2], log[3].copy(), np.array([0, len(log[0])], np.int64), DT)


def params_of(disp, sensor=None) -> Params:
    init = InitialState(np.zeros(3), np.diag([30.0**2, 30.0**2, 0.05**2]))
    return Params(ActionModel(np.asarray(disp, float), np.diag(STD**2), DT), sensor or pinhole_cubic(), (init,))


def exact_posterior(pose, eps=1e-9) -> Posterior:
    """Posterior concentrated on the true poses (covariance eps I, delta information I/eps)."""
    P, N = len(pose), len(pose) - 1
    cov = np.broadcast_to(eps * np.eye(3), (P, 3, 3)).copy()
    return Posterior(pose.copy(), cov, pose.copy(), cov.copy(),
                     np.broadcast_to(np.eye(3) / eps, (N, 3, 3)).copy(), pose[1:] / eps, 0.0, np.full(N, np.nan))


def per_action_true_mean(log, n_act):
    d = geo.rel_disp(log[4][:-1], log[4][1:])
    return np.array([d[log[0] == a].mean(axis=0) if (log[0] == a).any() else np.full(3, np.nan) for a in range(n_act)])


@pytest.fixture(scope="module")
def synth():
    rng = np.random.default_rng(21)
    n_act = 12
    vel = np.column_stack([rng.uniform(-250, 250, n_act), rng.uniform(-250, 250, n_act), rng.uniform(-1.5, 1.5, n_act)])
    log = simulate(rng, 6000, vel)
    return vel, log


# --------------------------------------------------------------------------- action M-step


def test_action_mstep_exact_posterior_recovers_true_displacements(synth):
    vel, log = synth
    n_act = 40
    start = np.zeros((n_act, 3))
    start[30] = [1.0, 2.0, 0.3]  # never executed: must be kept
    params = params_of(start)
    post = exact_posterior(log[4])
    new = am.update_action_model(params, batch_of(log), post)
    truth = per_action_true_mean(log, n_act)
    ex = np.unique(log[0])
    np.testing.assert_allclose(new.disp[ex], truth[ex], rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(new.disp[30], start[30])
    np.testing.assert_array_equal(new.cov, params.action.cov)
    assert new.dt == DT
    # learned noise: the spread of the true displacements about their per-action means
    new2 = am.update_action_model(params, batch_of(log), post, learn_noise=True)
    np.testing.assert_allclose(np.sqrt(np.diag(new2.cov)), STD, rtol=0.05)
    np.testing.assert_array_equal(new2.disp, new.disp)


def test_action_statistics_prior_pull():
    """With an uninformative delta the statistics fall back to the previous action model."""
    rng = np.random.default_rng(0)
    vel = np.array([[100.0, 50.0, 0.5]])
    log = simulate(rng, 60, vel)
    post = exact_posterior(log[4], eps=1e-9)
    post.info_delta[:] = 0.0
    post.vec_delta[:] = 0.0
    params = params_of(vel * DT)
    mu, C = am.action_statistics(params, batch_of(log), post)
    np.testing.assert_allclose(mu, np.broadcast_to(vel * DT, mu.shape), atol=1e-12)
    np.testing.assert_allclose(C, np.broadcast_to(params.action.cov, C.shape), rtol=1e-12)


def test_action_mstep_from_smoother_stays_near_truth(synth):
    vel, log = synth
    n_act = len(vel)
    params = params_of(vel * DT)
    batch = batch_of(log)
    post = smooth(params, batch)
    new = am.update_action_model(params, batch, post)
    truth = per_action_true_mean(log, n_act)  # what the true poses say
    err = np.abs(new.disp - vel * DT) / DT  # mm/s, mm/s, rad/s vs the true velocities
    yard = np.abs(truth - vel * DT) / DT
    rms = np.sqrt((err**2).mean(axis=0))
    rms_yard = np.sqrt((yard**2).mean(axis=0))
    assert (rms < np.maximum(3.0 * rms_yard, [10.0, 10.0, 0.03])).all(), (rms, rms_yard)
    # and far closer to the truth than a zero-velocity start is
    zero = am.update_action_model(params_of(np.zeros((n_act, 3))), batch, post)
    assert np.sqrt(((zero.disp - vel * DT) ** 2).mean()) > np.sqrt(((new.disp - vel * DT) ** 2).mean())


# --------------------------------------------------------------------------- sensor M-step


def test_fit_polynomial_well_conditioned_exact_cubic():
    coef = np.array([80.0, -0.04, 8.0e-6, -6.0e-10])
    d = np.linspace(1275.0, 4175.0, 300)
    h = np.polynomial.polynomial.polyval(d, coef)
    w = np.full_like(d, 0.7)
    got = sms.fit_polynomial(d, h, w, 3)
    np.testing.assert_allclose(got, coef, rtol=1e-8)
    # lower degree is zero-padded, weights matter
    lin = sms.fit_polynomial(d, 3.0 + 0.01 * d, w, 3)
    np.testing.assert_allclose(lin, [3.0, 0.01, 0.0, 0.0], atol=1e-9)
    h2 = h.copy()
    h2[::2] += 5.0
    w2 = np.where(np.arange(len(d)) % 2 == 0, 1e-12, 1.0)
    np.testing.assert_allclose(sms.fit_polynomial(d, h2, w2, 3), coef, rtol=1e-6)
    # weights act on SQUARED residuals: weight k == the point repeated k times
    rng = np.random.default_rng(0)
    dr = rng.uniform(1275.0, 4175.0, 40)
    hr = 57000.0 / dr + rng.standard_normal(40)
    k = rng.integers(1, 5, 40)
    np.testing.assert_allclose(sms.fit_polynomial(dr, hr, k.astype(float), 3),
                               sms.fit_polynomial(np.repeat(dr, k), np.repeat(hr, k), np.ones(k.sum()), 3), rtol=1e-8)


def _sensor_case(rng, T, sensor, height=None):
    vel = np.column_stack([rng.uniform(-250, 250, 12), rng.uniform(-250, 250, 12), rng.uniform(-1.5, 1.5, 12)])
    log = simulate(rng, T, vel, sensor=sensor, height=height)
    return params_of(vel * DT, PAPER_LIKE), batch_of(log), exact_posterior(log[4], eps=1e-10), log


PAPER_LIKE = SensorModel(np.array([40.0, -0.005]), 10.0, 0.2)  # the previous model does not matter


def test_sensor_mstep_recovers_cubic_and_sigmas():
    rng = np.random.default_rng(4)
    true = SensorModel(np.array([80.0, -0.04, 8.0e-6, -6.0e-10]), 1.2, 0.04)
    params, batch, post, log = _sensor_case(rng, 20000, true)
    new = sms.update_sensor_model(params, batch, post, np.random.default_rng(0))
    d = np.linspace(*new.distance_range_mm, 50)
    assert np.abs(new.height(d) - true.height(d)).max() < 0.25  # ~6600 sightings, sigma 1.2 px
    assert new.sigma_height == pytest.approx(true.sigma_height, rel=0.03)
    assert new.sigma_angle == pytest.approx(true.sigma_angle, rel=0.03)
    dm = np.hypot(*(batch.beacon_xy[batch.used] - log[4][1:][batch.used, :2]).T)
    assert new.distance_range_mm == pytest.approx((dm.min(), dm.max()))
    # without height noise the coefficients themselves come back
    quiet = SensorModel(true.coef, 1e-6, 0.04)
    params, batch, post, log = _sensor_case(np.random.default_rng(5), 3000, quiet)
    new = sms.update_sensor_model(params, batch, post, np.random.default_rng(0))
    np.testing.assert_allclose(new.coef, true.coef, rtol=1e-5)
    assert new.sigma_height < 1e-5


def test_sensor_mstep_pinhole_curve():
    rng = np.random.default_rng(8)
    true = pinhole_cubic(sh=1.0, sa=0.03)
    params, batch, post, log = _sensor_case(rng, 20000, true, height=PINHOLE)
    new = sms.update_sensor_model(params, batch, post, np.random.default_rng(1))
    lo, hi = new.distance_range_mm
    d = np.linspace(lo, hi, 200)
    rms = np.sqrt(np.mean((new.height(d) - PINHOLE(d)) ** 2))
    assert rms < 0.35  # a cubic cannot do much better than ~0.2 px on 1275-4175 mm
    assert 0.98 * true.sigma_height < new.sigma_height < 1.1 * true.sigma_height  # noise + cubic misfit
    assert new.sigma_angle == pytest.approx(true.sigma_angle, rel=0.03)


def test_sensor_points_methods_agree_on_average():
    rng = np.random.default_rng(6)
    vel = np.column_stack([rng.uniform(-250, 250, 12), rng.uniform(-250, 250, 12), rng.uniform(-1.5, 1.5, 12)])
    log = simulate(rng, 3000, vel)
    params = params_of(vel * DT)
    batch = batch_of(log)
    post = smooth(params, batch)
    n_used = int(batch.used.sum())
    d1, b1, o1, w1 = sms.sensor_points(params, batch, post, np.random.default_rng(0), "sample", n_samples=1)
    assert d1.shape == (n_used,) and o1.shape == (n_used, 2) and np.allclose(w1, 1.0)
    dc, bc, oc, wc = sms.sensor_points(params, batch, post, None, "cubature")
    assert dc.shape == (6 * n_used,) and np.allclose(wc, 1 / 6)
    np.testing.assert_array_equal(oc[::6], batch.obs[batch.used])
    ds, bs, os_, ws = sms.sensor_points(params, batch, post, np.random.default_rng(1), "sample", n_samples=200)
    # per-sighting weighted means of the distance agree (to Monte-Carlo error)
    mean_c = (dc * wc).reshape(n_used, 6).sum(1)
    mean_s = (ds * ws).reshape(n_used, 200).sum(1)
    sd = np.sqrt((wc * (dc - np.repeat(mean_c, 6)) ** 2).reshape(n_used, 6).sum(1))
    assert np.abs(mean_s - mean_c).mean() < 0.1 * sd.mean()
    var_s = (ws * (ds - np.repeat(mean_s, 200)) ** 2).reshape(n_used, 200).sum(1)
    assert np.sqrt(var_s).mean() == pytest.approx(sd.mean(), rel=0.05)
    m_s = sms.update_sensor_model(params, batch, post, np.random.default_rng(2), "sample", n_samples=50)
    m_c = sms.update_sensor_model(params, batch, post, None, "cubature")
    dd = np.linspace(*m_c.distance_range_mm, 50)
    assert np.abs(m_s.height(dd) - m_c.height(dd)).max() < 0.1
    assert m_s.sigma_height == pytest.approx(m_c.sigma_height, rel=0.02)
    assert m_s.sigma_angle == pytest.approx(m_c.sigma_angle, rel=0.02)
    assert m_s.distance_range_mm == m_c.distance_range_mm
    # one sample per sighting (the paper) is reproducible with the same seed
    a = sms.update_sensor_model(params, batch, post, np.random.default_rng(3))
    b = sms.update_sensor_model(params, batch, post, np.random.default_rng(3))
    np.testing.assert_array_equal(a.coef, b.coef)
    with pytest.raises(ValueError):
        sms.sensor_points(params, batch, post, np.random.default_rng(0), "unscented")
