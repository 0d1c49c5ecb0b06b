"""Tests of learners.em.geometry and the reference E-step learners.em.smoother."""

from __future__ import annotations

import numpy as np
import pytest

from aibo_core import geometry as geo
from learners.em import smoother as sm
from learners.em.data import Batch
from learners.em.params import ActionModel, InitialState, Params, SensorModel

DT = 1.0 / 30.0
STD = np.array([5.0, 5.0, 0.03])  # true (and model) per-frame motion noise, mm mm rad
BEACONS = np.array([[-2700.0, -1800.0], [2700.0, -1800.0], [-2700.0, 1800.0], [2700.0, 1800.0]])


# --------------------------------------------------------------------------- synthetic data


def pinhole_cubic() -> SensorModel:
    d = np.linspace(1000.0, 4500.0, 200)
    coef = np.polynomial.Polynomial.fit(d, 57000.0 / d, 3).convert().coef
    return SensorModel(coef, 1.5, 0.05)


def random_velocities(rng, n=40):
    vel = np.zeros((n, 3))
    vel[:, 0] = rng.uniform(-150, 150, n)
    vel[:, 1] = rng.uniform(-150, 150, n)
    vel[:, 2] = rng.uniform(-1.5, 1.5, n)
    return vel


def simulate(rng, T, vel, seg=30, p_seen=0.6, sensor=None, start=(0.0, 0.0, 0.0), actions=None):
    """A random trajectory of T frames: (actions, obs, beacon_xy, seen, true poses (T+1, 3))."""
    sensor = sensor or pinhole_cubic()
    if actions is None:
        actions = np.repeat(rng.integers(0, len(vel), T // seg + 1), seg)[:T]
    pose = np.empty((T + 1, 3))
    pose[0] = start
    noise = rng.standard_normal((T, 3)) * STD
    for i in range(T):
        pose[i + 1] = geo.motion(pose[i], vel[actions[i]] * DT + noise[i])[0]
    seen = rng.random(T) < p_seen
    b = rng.integers(0, len(BEACONS), T)
    h, _, _ = geo.observe(pose[1:], BEACONS[b], sensor)
    obs = h + rng.standard_normal((T, 2)) * [sensor.sigma_height, sensor.sigma_angle]
    obs[:, 1] = geo.wrap(obs[:, 1])
    obs[~seen] = np.nan
    bxy = np.where(seen[:, None], BEACONS[b], np.nan)
    return np.asarray(actions, np.int64), obs, bxy, seen, pose


def batch_of(logs) -> Batch:
    fs = np.concatenate([[0], np.cumsum([len(lg[0]) for lg in logs])]).astype(np.int64)
    cat = lambda j: np.concatenate([lg[j] for lg in logs])  # noqa: E731
    return Batch(cat(0).astype(np.int64), cat(1), cat(2), cat(3).astype(bool), fs, DT)


def true_params(vel, sensor=None, inits=None, n_logs=1) -> Params:
    inits = inits or tuple(InitialState(np.zeros(3), np.diag([30.0**2, 30.0**2, 0.05**2])) for _ in range(n_logs))
    return Params(ActionModel(vel * DT, np.diag(STD**2), DT), sensor or pinhole_cubic(), tuple(inits))


@pytest.fixture(scope="module")
def aibo_run():
    rng = np.random.default_rng(1)
    vel = random_velocities(rng)
    log = simulate(rng, 900, vel)
    params = true_params(vel)
    batch = batch_of([log])
    return params, batch, log[4], sm.smooth(params, batch)


# --------------------------------------------------------------------------- geometry


def test_wrap_range_and_identity():
    a = np.array([np.pi, -np.pi, 3 * np.pi, -3 * np.pi, 0.3, -0.3, 7.0, -7.0, 1e-17])
    w = geo.wrap(a)
    assert np.all(w > -np.pi) and np.all(w <= np.pi)
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-12)
    np.testing.assert_allclose(np.sin(w), np.sin(a), atol=1e-12)
    assert w[0] == np.pi and w[1] == np.pi
    assert w[4] == 0.3 and w[8] == 1e-17  # in-range values unchanged bit for bit


def _numjac(fun, x, eps=1e-6):
    x = np.asarray(x, float)
    cols = []
    for j in range(len(x)):
        e = np.zeros_like(x)
        e[j] = eps
        cols.append((fun(x + e) - fun(x - e)) / (2 * eps))
    return np.stack(cols, axis=-1)


def test_jacobians_match_finite_differences():
    rng = np.random.default_rng(0)
    sensor = pinhole_cubic()
    for _ in range(5):
        s = np.array([rng.uniform(-1000, 1000), rng.uniform(-1000, 1000), rng.uniform(-10, 10)])
        u = np.array([rng.uniform(-20, 20), rng.uniform(-20, 20), rng.uniform(-0.1, 0.1)])
        g, F, R3 = geo.motion(s, u)
        np.testing.assert_allclose(F, _numjac(lambda x: geo.motion(x, u)[0], s), atol=1e-6)
        np.testing.assert_allclose(R3[:2, :2], geo.rot(s[2]), atol=0)
        np.testing.assert_allclose(geo.rel_disp(s, g), u, atol=1e-9)
        # the vectorized path gives the same numbers as the one-pose path
        gv, Fv, Rv = geo.motion(s[None], u[None])
        np.testing.assert_allclose(gv[0], g, rtol=1e-14)
        np.testing.assert_allclose(Fv[0], F, rtol=1e-14, atol=1e-14)
        b = BEACONS[rng.integers(4)]
        h, H, d = geo.observe(s, b, sensor)
        assert d == pytest.approx(np.hypot(*(b - s[:2])))
        assert h[0] == pytest.approx(float(sensor.height(d)), rel=1e-12)

        def hh(x):
            out = geo.observe(x, b, sensor)[0]
            out[1] = geo.wrap(out[1] - h[1])  # difference near the linearization point
            return out

        np.testing.assert_allclose(H, _numjac(hh, s), atol=1e-6)
        s1 = s + np.array([30.0, -20.0, 0.2])
        L1, L2, m = geo.rel_disp_jac(s, s1)
        np.testing.assert_allclose(L1, _numjac(lambda x: geo.rel_disp(x, s1), s), atol=1e-6)
        np.testing.assert_allclose(L2, _numjac(lambda x: geo.rel_disp(s, x), s1), atol=1e-6)
        np.testing.assert_allclose(L1 @ s + L2 @ s1 + m, geo.rel_disp(s, s1), atol=1e-9)


# --------------------------------------------------------------------------- linear-Gaussian


def kalman_rts(mu0, P0, Fs, bs, Q, C, R, z, has_obs):
    """Textbook Kalman filter (standard update) + Rauch-Tung-Striebel smoother."""
    T, n = len(Fs), len(mu0)
    mf = np.empty((T + 1, n))
    Pf = np.empty((T + 1, n, n))
    mp = np.empty((T, n))
    Pp = np.empty((T, n, n))
    mf[0], Pf[0] = mu0, P0
    ll = 0.0
    for t in range(T):
        mp[t] = Fs[t] @ mf[t] + bs[t]
        Pp[t] = Fs[t] @ Pf[t] @ Fs[t].T + Q
        m, P = mp[t], Pp[t]
        if has_obs[t]:
            S = C @ P @ C.T + R
            K = P @ C.T @ np.linalg.inv(S)
            v = z[t] - C @ m
            ll += -0.5 * (v @ np.linalg.solve(S, v) + np.log(np.linalg.det(S)) + len(v) * np.log(2 * np.pi))
            m = m + K @ v
            P = P - K @ S @ K.T
        mf[t + 1], Pf[t + 1] = m, P
    ms, Ps = mf.copy(), Pf.copy()
    for t in range(T - 1, -1, -1):
        G = Pf[t] @ Fs[t].T @ np.linalg.inv(Pp[t])
        ms[t] = mf[t] + G @ (ms[t + 1] - mp[t])
        Ps[t] = Pf[t] + G @ (Ps[t + 1] - Pp[t]) @ G.T
    return mf, Pf, ms, Ps, ll


@pytest.mark.parametrize("general_F", [False, True])
def test_linear_gaussian_equals_kalman_rts(general_F):
    rng = np.random.default_rng(7)
    T, n = 120, 3
    drift = np.array([1.0, -0.5, 0.2])
    A = rng.standard_normal((n, n))
    Q = A @ A.T * 0.1 + 0.05 * np.eye(n)
    C = rng.standard_normal((2, n))
    R = np.array([[0.5, 0.1], [0.1, 0.3]])
    if general_F:
        Fs = np.eye(n) + 0.1 * rng.standard_normal((T, n, n))
    else:
        Fs = np.broadcast_to(np.eye(n), (T, n, n)).copy()
    bs = np.broadcast_to(drift, (T, n)).copy()
    x = np.zeros((T + 1, n))
    for t in range(T):
        x[t + 1] = Fs[t] @ x[t] + bs[t] + rng.multivariate_normal(np.zeros(n), Q)
    has_obs = rng.random(T) < 0.6
    has_obs[-5:] = False  # the last frames unobserved: beta = "infinity" must still work
    z = x[1:] @ C.T + rng.multivariate_normal(np.zeros(2), R, size=T)
    mu0, P0 = np.array([0.5, 0.0, -0.5]), np.diag([2.0, 1.0, 3.0])

    motion = lambda i, m: (Fs[i] @ m + bs[i], Fs[i], Q)  # noqa: E731
    observe = lambda i, m: (C @ m, C, R, z[i], None) if has_obs[i] else None  # noqa: E731
    res = sm.two_filter_smooth(mu0, P0, T, motion, observe)
    mf, Pf, ms, Ps, ll = kalman_rts(mu0, P0, Fs, bs, Q, C, R, z, has_obs)

    np.testing.assert_allclose(res.forward.mu, mf, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(res.forward.cov, Pf, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(res.mu, ms, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(res.cov, Ps, rtol=1e-8, atol=1e-8)
    assert res.forward.loglik == pytest.approx(ll, rel=1e-10)
    assert np.isnan(res.forward.mahal2[~has_obs]).all() and np.isfinite(res.forward.mahal2[has_obs]).all()
    # beta at the last pose carries no information; the smoothed end equals the filtered end
    assert not res.Y[-1].any()
    np.testing.assert_allclose(res.mu[-1], res.forward.mu[-1], atol=1e-12)


# --------------------------------------------------------------------------- aibo model


def test_aibo_posterior_shapes_and_mahal2(aibo_run):
    params, batch, pose, post = aibo_run
    N = batch.n_frames
    assert post.mu_alpha.shape == (N + 1, 3) and post.cov_gamma.shape == (N + 1, 3, 3)
    assert post.info_delta.shape == (N, 3, 3) and post.vec_delta.shape == (N, 3)
    assert np.isnan(post.mahal2[~batch.used]).all()
    assert np.isfinite(post.mahal2[batch.used]).all()
    # consistent model: E[mahal2] = 2 (two observation components)
    assert 1.7 < post.mahal2[batch.used].mean() < 2.3
    assert np.isfinite(post.loglik)


def test_aibo_obs_info_vectorized_equals_generic_loop(aibo_run):
    params, batch, pose, post = aibo_run
    motion, observe, obs_info = sm.aibo_model(params, batch.actions, batch.obs, batch.beacon_xy, batch.used)
    dY1, dy1 = sm.observation_information(post.mu_alpha, observe, batch.used)
    dY2, dy2 = obs_info(post.mu_alpha, batch.used)
    np.testing.assert_allclose(dY2, dY1, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(dy2, dy1, rtol=1e-12, atol=1e-12)


def test_aibo_covariances_spd_and_smaller_than_filtered(aibo_run):
    params, batch, pose, post = aibo_run
    for C in (post.cov_alpha, post.cov_gamma):
        np.testing.assert_array_equal(C, np.swapaxes(C, 1, 2))
        assert np.linalg.eigvalsh(C).min() > 0
    diff = np.linalg.eigvalsh(post.cov_alpha - post.cov_gamma)
    scale = np.linalg.eigvalsh(post.cov_alpha).max(axis=1)
    assert (diff.min(axis=1) >= -1e-9 * scale).all()
    # and strictly smaller somewhere before the end
    assert np.trace(post.cov_gamma[:-1], axis1=1, axis2=2).sum() < 0.8 * np.trace(post.cov_alpha[:-1], axis1=1, axis2=2).sum()


def test_aibo_smoothed_closer_to_truth(aibo_run):
    params, batch, pose, post = aibo_run
    ea = np.linalg.norm(post.mu_alpha[:, :2] - pose[:, :2], axis=1).mean()
    eg = np.linalg.norm(post.mu_gamma[:, :2] - pose[:, :2], axis=1).mean()
    ha = np.abs(post.mu_alpha[:, 2] - pose[:, 2]).mean()
    hg = np.abs(post.mu_gamma[:, 2] - pose[:, 2]).mean()
    assert eg < 0.9 * ea and hg < 0.9 * ha
    assert eg < 60.0 and hg < 0.06
    # the posterior covers the truth: normalized squared errors average about 3
    e = post.mu_gamma - pose
    nees = np.einsum("pi,pij,pj->p", e, np.linalg.inv(post.cov_gamma), e).mean()
    assert 1.5 < nees < 5.0


def test_heading_wrap_many_turns():
    rng = np.random.default_rng(3)
    vel = np.array([[40.0, 0.0, 3.0], [0.0, 40.0, -2.5]])
    actions = np.zeros(700, np.int64)
    actions[450:] = 1
    start = (0.0, 0.0, 3.1)
    log = simulate(rng, 700, vel, actions=actions, start=start)
    pose = log[4]
    assert pose[:, 2].max() - pose[:, 2].min() > 6 * np.pi  # several full circles
    ang = log[1][log[3], 1]
    assert (ang > 3.0).any() and (ang < -3.0).any()  # sightings straddle +-pi
    init = InitialState(np.array(start), np.diag([30.0**2, 30.0**2, 0.05**2]))
    params = true_params(vel, inits=(init,))
    post = sm.smooth(params, batch_of([log]))
    assert np.abs(post.mu_gamma[:, 2] - pose[:, 2]).max() < 0.15  # unwrapped, no 2pi jumps
    assert np.sqrt(((post.mu_gamma[:, :2] - pose[:, :2]) ** 2).sum(1).mean()) < 60.0
    # shifting the whole problem by 2pi in heading shifts the means by 2pi, nothing else
    init2 = InitialState(np.array(start) + [0, 0, 2 * np.pi], init.cov)
    post2 = sm.smooth(params.with_(init=(init2,)), batch_of([log]))
    np.testing.assert_allclose(post2.mu_gamma - [0, 0, 2 * np.pi], post.mu_gamma, atol=1e-7)
    np.testing.assert_allclose(post2.cov_gamma, post.cov_gamma, rtol=1e-6, atol=1e-9)
    assert post2.loglik == pytest.approx(post.loglik, rel=1e-9)


def test_several_logs_equal_each_alone():
    rng = np.random.default_rng(5)
    vel = random_velocities(rng)
    lengths = [250, 1, 57, 400]
    logs = [simulate(rng, T, vel, start=(100.0 * k, -50.0 * k, 0.3 * k)) for k, T in enumerate(lengths)]
    inits = tuple(InitialState(np.array([100.0 * k, -50.0 * k, 0.3 * k]), np.diag([900.0, 400.0, 0.01 + 0.01 * k]))
                  for k in range(len(logs)))
    params = true_params(vel, inits=inits)
    batch = batch_of(logs)
    post = sm.smooth(params, batch)
    ll = 0.0
    for k, lg in enumerate(logs):
        one = sm.smooth(params.with_(init=(inits[k],)), batch_of([lg]))
        ps = slice(batch.pose_start[k], batch.pose_start[k + 1])
        fs = slice(batch.frame_start[k], batch.frame_start[k + 1])
        for name, sl in [("mu_alpha", ps), ("cov_alpha", ps), ("mu_gamma", ps), ("cov_gamma", ps),
                         ("info_delta", fs), ("vec_delta", fs), ("mahal2", fs)]:
            np.testing.assert_array_equal(getattr(post, name)[sl], getattr(one, name), err_msg=f"log {k} {name}")
        np.testing.assert_array_equal(post.mu_alpha[ps][0], inits[k].mean)
        ll += one.loglik
    assert post.loglik == pytest.approx(ll, rel=1e-12)


def test_gating_outlier():
    rng = np.random.default_rng(11)
    vel = random_velocities(rng)
    log = simulate(rng, 600, vel)
    params = true_params(vel)
    batch = batch_of([log])
    j = int(np.flatnonzero(batch.used)[200])
    batch.obs[j, 0] += 60.0  # gross height outlier
    batch.obs[j, 1] = geo.wrap(batch.obs[j, 1] + 2.0)
    plain = sm.smooth(params, batch)
    assert plain.mahal2[j] > 1000.0
    gated = sm.smooth(params, batch, gate=13.8)
    assert gated.mahal2[j] > 13.8
    pruned = batch.used & (gated.mahal2 > 13.8)
    assert pruned[j]
    removed = sm.smooth(params, batch.with_used(batch.used & ~pruned))
    for name in ("mu_alpha", "cov_alpha", "mu_gamma", "cov_gamma", "info_delta", "vec_delta"):
        np.testing.assert_allclose(getattr(gated, name), getattr(removed, name), rtol=1e-12, atol=1e-12, err_msg=name)
    assert gated.loglik == pytest.approx(removed.loglik, rel=1e-12)
    keep = ~pruned
    np.testing.assert_array_equal(gated.mahal2[keep], removed.mahal2[keep])
    # the outlier did distort the ungated posterior
    assert np.abs(plain.mu_gamma - gated.mu_gamma).max() > 1.0


def test_non_finite_raises_naming_log_and_frame():
    rng = np.random.default_rng(2)
    vel = random_velocities(rng)
    logs = [simulate(rng, 50, vel), simulate(rng, 60, vel)]
    batch = batch_of(logs)
    j = int(np.flatnonzero(batch.used[50:])[3]) + 50
    batch.obs[j, 0] = np.nan
    with pytest.raises(FloatingPointError, match=rf"log 1, frame {j - 50}\b"):
        sm.smooth(true_params(vel, n_logs=2), batch)
    with pytest.raises(ValueError):
        sm.smooth(true_params(vel, n_logs=1), batch)
