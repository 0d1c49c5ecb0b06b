"""Tests of the M-step statistics (learners.inference.action_stats, learners.inference.sensor_stats)
on exact and smoothed posteriors of synthetic logs (tests/_synth.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from aibo_core import geometry as geo
from learners.arrays.lowered import BASIS_INVERSE, BASIS_POWER, curve
from learners.arrays.posterior import Posterior
from learners.inference import action_stats as ast
from learners.inference import sensor_stats as sst
from learners.inference.reference import smooth
from tests._synth import pinhole_coef, simulate, true_table


def exact_posterior(batch, pose, eps=1e-9) -> Posterior:
    """Posterior concentrated on the true poses (covariance eps I, delta information I/eps)."""
    P, N = len(pose), batch.n_frames
    cov = np.broadcast_to(eps * np.eye(3), (P, 3, 3)).copy()
    end = batch.frame_to_pose + 1
    return Posterior(pose.copy(), cov, pose.copy(), cov.copy(), np.broadcast_to(np.eye(3) / eps, (N, 3, 3)).copy(),
                     pose[end] / eps, 0.0, np.full(batch.n_sightings, np.nan))  # fmt: skip


def true_net_disp(batch, lo, pose):
    """R(-theta_i)(s_{i+1} - s_i - offset_i) of the true poses, (N, 3)."""
    p = batch.frame_to_pose
    return geo.rel_disp(pose[p], pose[p + 1] - lo.offset)


@pytest.fixture(scope="module")
def synth():
    rng = np.random.default_rng(21)
    table = true_table(rng)
    batch, lo, pose = simulate(rng, [3000, 1500], table, effects=True, max_per_frame=2)
    return table, batch, lo, pose


# --------------------------------------------------------------------------- action statistics


def test_action_statistics_exact_posterior_recover_the_displacements(synth):
    table, batch, lo, pose = synth
    start = replace(lo, disp=np.zeros_like(lo.disp))  # the prior hardly matters with an exact posterior
    mu, C_sum = ast.action_statistics(start, batch, exact_posterior(batch, pose), True)
    # prior pull ~ eps / var: the smallest frame variance is a quarter of Sigma_A's (cov_sd down to 0.5)
    np.testing.assert_allclose(mu, true_net_disp(batch, lo, pose), rtol=1e-4, atol=1e-4)
    assert np.abs(C_sum).max() < 1e-6 * batch.n_frames * lo.cov.max()  # vs the prior's n Sigma
    # the noise: residuals about the true table, normalized by the cov scales and each component's factor (cov_sd):
    # without the factors the sigmas are off (the test below)
    R = ast.residual_cov(mu, table[batch.actions], lo.cov_scale, lo.cov_sd) / batch.n_frames
    np.testing.assert_allclose(np.sqrt(np.diag(R)), np.sqrt(np.diag(lo.cov)), rtol=0.05)
    unscaled = ast.residual_cov(mu, table[batch.actions], lo.cov_scale) / batch.n_frames
    assert np.abs(np.sqrt(np.diag(unscaled)) / np.sqrt(np.diag(lo.cov)) - 1.0).max() > 0.15
    # ignoring the offsets biases the statistics by R(-theta) offset
    mu0, _ = ast.action_statistics(replace(start, offset=np.zeros_like(lo.offset)), batch,
                                   exact_posterior(batch, pose), False)  # fmt: skip
    assert np.abs(mu0 - mu).max() > 1.0


def test_action_statistics_prior_pull(synth):
    """With an uninformative delta the statistics are the prior: mu* = disp, C*_i = cov_scale_i Sigma."""
    table, batch, lo, pose = synth
    post = exact_posterior(batch, pose)
    post.info_delta[:] = 0.0
    post.vec_delta[:] = 0.0
    mu, C_sum = ast.action_statistics(lo, batch, post, True)
    np.testing.assert_allclose(mu, lo.disp, atol=1e-12)
    np.testing.assert_allclose(C_sum, batch.n_frames * lo.cov, rtol=1e-12)


def test_action_statistics_from_smoother_stay_near_truth(synth):
    table, batch, lo, pose = synth
    post = smooth(lo, batch)
    mu, _ = ast.action_statistics(lo, batch, post, False)
    truth = true_net_disp(batch, lo, pose)
    n_act = len(table)
    means = np.array([mu[batch.actions == a].mean(0) if (batch.actions == a).any() else table[a] for a in range(n_act)])
    yard = np.array([truth[batch.actions == a].mean(0) if (batch.actions == a).any() else table[a]
                     for a in range(n_act)])  # fmt: skip
    err = np.sqrt(((means - table) ** 2).mean(0))
    err_yard = np.sqrt(((yard - table) ** 2).mean(0))
    assert (err < np.maximum(3.0 * err_yard, [0.3, 0.3, 1e-3])).all(), (err, err_yard)
    # and far closer to the truth than the zero-displacement prior
    mu0, _ = ast.action_statistics(replace(lo, disp=np.zeros_like(lo.disp)), batch, post, False)
    assert np.sqrt(((mu0 - truth) ** 2).mean()) > np.sqrt(((mu - truth) ** 2).mean())


# --------------------------------------------------------------------------- sensor curve


def test_fit_polynomial_well_conditioned_exact_cubic():
    coef = np.array([80.0, -0.04, 8.0e-6, -6.0e-10])
    d = np.linspace(1275.0, 4175.0, 300)
    h = np.polynomial.polynomial.polyval(d, coef)
    w = np.full_like(d, 0.7)
    np.testing.assert_allclose(sst.fit_polynomial(d, h, w, 3), coef, rtol=1e-8)
    lin = sst.fit_polynomial(d, 3.0 + 0.01 * d, w, 3)  # lower degree is zero-padded
    np.testing.assert_allclose(lin, [3.0, 0.01, 0.0, 0.0], atol=1e-9)
    h2 = h.copy()
    h2[::2] += 5.0
    w2 = np.where(np.arange(len(d)) % 2 == 0, 1e-12, 1.0)  # weights matter
    np.testing.assert_allclose(sst.fit_polynomial(d, h2, w2, 3), coef, rtol=1e-6)
    # a column scale s: fits s f(d) = h
    s = np.linspace(0.8, 1.2, len(d))
    np.testing.assert_allclose(sst.fit_polynomial(d, s * h, w, 3, scale=s), coef, rtol=1e-8)
    # weights act on SQUARED residuals: weight k == the point repeated k times
    rng = np.random.default_rng(0)
    dr = rng.uniform(1275.0, 4175.0, 40)
    hr = 57000.0 / dr + rng.standard_normal(40)
    k = rng.integers(1, 5, 40)
    np.testing.assert_allclose(sst.fit_polynomial(dr, hr, k.astype(float), 3),
                               sst.fit_polynomial(np.repeat(dr, k), np.repeat(hr, k), np.ones(k.sum()), 3), rtol=1e-8)


@pytest.mark.parametrize("basis", [BASIS_POWER, BASIS_INVERSE])
@pytest.mark.parametrize("effects", [False, True])
def test_sensor_curve_recovers_truth(basis, effects):
    rng = np.random.default_rng(4 + basis + 2 * effects)
    batch, lo, pose = simulate(rng, [8000], true_table(rng), basis=basis, effects=effects, max_per_frame=2,
                               sigma=(1.2, 0.04))  # fmt: skip
    post = exact_posterior(batch, pose, eps=1e-10)
    start = replace(lo, coef=np.array([40.0, -0.005]), sigma_size=10.0, sigma_bearing=0.2)  # does not matter
    coef, s_s, s_b, rng_d = sst.update_sensor_curve(start, batch, post, np.random.default_rng(0))
    d = np.linspace(*rng_d, 50)
    assert np.abs(curve(basis, coef, d)[0] - curve(basis, pinhole_coef(basis), d)[0]).max() < 0.5
    assert s_s == pytest.approx(1.2, rel=0.04) and s_b == pytest.approx(0.04, rel=0.04)
    dm = np.hypot(*(batch.sight_xy - pose[batch.sight_pose, :2]).T)
    assert rng_d == pytest.approx((dm.min(), dm.max()))
    if effects:  # a fit that ignores the per-sighting effects is visibly worse
        plain = replace(start, size_scale=np.ones_like(lo.size_scale), size_offset=np.zeros_like(lo.size_offset),
                        size_var_factor=np.ones_like(lo.size_var_factor),
                        bearing_offset=np.zeros_like(lo.bearing_offset))  # fmt: skip
        _, s_s0, s_b0, _ = sst.update_sensor_curve(plain, batch, post, np.random.default_rng(0))
        assert s_s0 > 1.5 * s_s and s_b0 > 1.2 * s_b


def test_sensor_points_methods_agree_on_average(synth):
    table, batch, lo, pose = synth
    post = smooth(lo, batch)
    n_used = int(batch.used.sum())
    d1, b1, i1, w1 = sst.sensor_points(lo, batch, post, np.random.default_rng(0), "sample", n_samples=1)
    assert d1.shape == (n_used,) and np.allclose(w1, 1.0)
    dc, bc, ic, wc = sst.sensor_points(lo, batch, post, None, "cubature")
    assert dc.shape == (6 * n_used,) and np.allclose(wc, 1 / 6)
    np.testing.assert_array_equal(ic[::6], np.flatnonzero(batch.used))
    ds, bs, is_, ws = sst.sensor_points(lo, batch, post, np.random.default_rng(1), "sample", n_samples=200)
    mean_c = (dc * wc).reshape(n_used, 6).sum(1)
    mean_s = (ds * ws).reshape(n_used, 200).sum(1)
    sd = np.sqrt((wc * (dc - np.repeat(mean_c, 6)) ** 2).reshape(n_used, 6).sum(1))
    assert np.abs(mean_s - mean_c).mean() < 0.1 * sd.mean()
    var_s = (ws * (ds - np.repeat(mean_s, 200)) ** 2).reshape(n_used, 200).sum(1)
    assert np.sqrt(var_s).mean() == pytest.approx(sd.mean(), rel=0.05)
    m_s = sst.update_sensor_curve(lo, batch, post, np.random.default_rng(2), "sample", n_samples=50)
    m_c = sst.update_sensor_curve(lo, batch, post, None, "cubature")
    dd = np.linspace(*m_c[3], 50)
    assert np.abs(curve(lo.basis, m_s[0], dd)[0] - curve(lo.basis, m_c[0], dd)[0]).max() < 0.1
    assert m_s[1] == pytest.approx(m_c[1], rel=0.02) and m_s[2] == pytest.approx(m_c[2], rel=0.02)
    assert m_s[3] == m_c[3]
    a = sst.update_sensor_curve(lo, batch, post, np.random.default_rng(3))
    b = sst.update_sensor_curve(lo, batch, post, np.random.default_rng(3))
    np.testing.assert_array_equal(a[0], b[0])
    with pytest.raises(ValueError):
        sst.sensor_points(lo, batch, post, np.random.default_rng(0), "unscented")


def test_fused_table_regression_equals_the_general_path():
    """The compiled one-hot fast path gives the very numbers of ActionModel.regress and residual_cov."""
    from learners.inference.action_stats import residual_cov
    from learners.inference.kernels import residual_cov_compiled, table_means_compiled, table_residual_cov_compiled
    from learners.model.action import ActionModel

    rng = np.random.default_rng(5)
    commands = rng.integers(0, 39, 5000)  # command 39 never executed: keeps its old weights
    mu_star = rng.normal(size=(5000, 3)) * [10.0, 10.0, 0.1]
    old = rng.normal(size=(40, 3))
    model = ActionModel(old, np.eye(3), 1 / 30)
    w = model.regress(commands, mu_star)
    np.testing.assert_array_equal(table_means_compiled(commands, mu_star, old), w)
    assert np.array_equal(w[39], old[39])
    scale = rng.uniform(0.5, 2.0, 5000)
    fused = table_residual_cov_compiled(commands, mu_star, w, scale)
    np.testing.assert_array_equal(fused, residual_cov_compiled(mu_star, w[commands], scale))  # same order
    np.testing.assert_allclose(fused, residual_cov(mu_star, w[commands], scale), rtol=1e-12)  # BLAS order
