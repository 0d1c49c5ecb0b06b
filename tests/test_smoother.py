"""Tests of aibo_core.geometry and the reference E-step learners.inference.reference."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from aibo_core import geometry as geo
from learners.arrays.lowered import BASIS_POWER
from learners.inference import reference as sm
from tests._synth import LANDMARKS as BEACONS
from tests._synth import pinhole_coef, simulate, true_table


class _Cubic:
    """The sensor curve for geometry.observe (height/dheight)."""

    coef = pinhole_coef(BASIS_POWER)

    def height(self, d):
        return np.polynomial.polynomial.polyval(d, self.coef)

    def dheight(self, d):
        return np.polynomial.polynomial.polyval(d, np.polynomial.polynomial.polyder(self.coef))


def pinhole_cubic():
    return _Cubic()


def truth_run(seed, lengths, **kw):
    """(batch, TRUE lowered model, true poses, reference posterior)."""
    rng = np.random.default_rng(seed)
    batch, lo, pose = simulate(rng, lengths, true_table(rng), **kw)
    return batch, lo, pose, sm.smooth(lo, batch)


@pytest.fixture(scope="module")
def aibo_run():
    return truth_run(1, [900], max_per_frame=2)


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
    obs_start = np.concatenate([[0], np.cumsum(has_obs)])
    frame_of = np.flatnonzero(has_obs)  # observation j is of frame frame_of[j]
    observe = lambda j, m: (C @ m, C, R, z[frame_of[j]], None)  # noqa: E731
    res = sm.two_filter_smooth(mu0, P0, obs_start, motion, observe)
    mf, Pf, ms, Ps, ll = kalman_rts(mu0, P0, Fs, bs, Q, C, R, z, has_obs)

    np.testing.assert_allclose(res.forward.mu, mf, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(res.forward.cov, Pf, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(res.mu, ms, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(res.cov, Ps, rtol=1e-8, atol=1e-8)
    assert res.forward.loglik == pytest.approx(ll, rel=1e-10)
    assert res.forward.mahal2.shape == (has_obs.sum(),) and np.isfinite(res.forward.mahal2).all()
    # beta at the last pose carries no information; the smoothed end equals the filtered end
    assert not res.Y[-1].any()
    np.testing.assert_allclose(res.mu[-1], res.forward.mu[-1], atol=1e-12)




def test_several_observations_per_frame_equal_one_stacked_update():
    """Linear-Gaussian: frame i's observations applied one after the other == one update with the
    stacked observation (block-diagonal noise), for the filter, the smoother and the likelihood."""
    rng = np.random.default_rng(3)
    T, n = 80, 3
    Fs = np.broadcast_to(np.eye(n), (T, n, n)).copy() + 0.05 * rng.standard_normal((T, n, n))
    bs = rng.standard_normal((T, n))
    A = rng.standard_normal((n, n))
    Q = A @ A.T * 0.1 + 0.05 * np.eye(n)
    counts = rng.integers(0, 4, T)  # 0..3 observations per frame
    counts[-3:] = 0
    Cs = rng.standard_normal((counts.sum(), 2, n))
    Rs = np.array([np.diag(rng.uniform(0.2, 0.6, 2)) for _ in range(counts.sum())])
    zs = rng.standard_normal((counts.sum(), 2)) * 3
    obs_start = np.concatenate([[0], np.cumsum(counts)])
    mu0, P0 = np.zeros(n), np.diag([2.0, 1.0, 3.0])
    motion = lambda i, m: (Fs[i] @ m + bs[i], Fs[i], Q)  # noqa: E731
    observe = lambda j, m: (Cs[j] @ m, Cs[j], Rs[j], zs[j], None)  # noqa: E731
    res = sm.two_filter_smooth(mu0, P0, obs_start, motion, observe)
    # stacked: one observation per frame with all of its rows
    Cb = [np.concatenate(Cs[obs_start[i]:obs_start[i + 1]]) if counts[i] else None for i in range(T)]
    zb = [np.concatenate(zs[obs_start[i]:obs_start[i + 1]]) if counts[i] else None for i in range(T)]
    Rb = [np.diag(np.concatenate([np.diag(r) for r in Rs[obs_start[i]:obs_start[i + 1]]])) if counts[i] else None
          for i in range(T)]  # fmt: skip
    has = counts > 0
    stacked = sm.two_filter_smooth(mu0, P0, np.concatenate([[0], np.cumsum(has)]), motion,
                                   lambda j, m: _stacked(j, m, Cb, Rb, zb, has))  # fmt: skip
    np.testing.assert_allclose(res.forward.mu, stacked.forward.mu, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(res.forward.cov, stacked.forward.cov, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(res.mu, stacked.mu, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(res.cov, stacked.cov, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(res.Y_delta, stacked.Y_delta, rtol=1e-9, atol=1e-9)
    assert res.forward.loglik == pytest.approx(stacked.forward.loglik, rel=1e-10)
    assert res.forward.mahal2.shape == (counts.sum(),)


def _stacked(j, m, Cb, Rb, zb, has):
    i = int(np.flatnonzero(has)[j])
    return Cb[i] @ m, Cb[i], Rb[i], zb[i], None


# --------------------------------------------------------------------------- aibo model


def test_aibo_posterior_shapes_and_mahal2(aibo_run):
    batch, lo, pose, post = aibo_run
    N, S = batch.n_frames, batch.n_sightings
    assert (np.diff(batch.sight_start) == 2).any()
    assert post.mu_alpha.shape == (N + 1, 3) and post.cov_gamma.shape == (N + 1, 3, 3)
    assert post.info_delta.shape == (N, 3, 3) and post.vec_delta.shape == (N, 3) and post.mahal2.shape == (S,)
    assert np.isfinite(post.mahal2).all()
    # consistent model: E[mahal2] = 2 (two observation components)
    assert 1.7 < post.mahal2.mean() < 2.3
    assert np.isfinite(post.loglik)


def test_aibo_obs_info_vectorized_equals_generic_loop(aibo_run):
    batch, lo, pose, post = aibo_run
    obs_start, motion, observe, obs_info = sm.aibo_model(lo, batch, 0)
    applied = np.ones(batch.n_sightings, bool)
    applied[::7] = False
    dY1, dy1 = sm.observation_information(post.mu_alpha, observe, obs_start, applied)
    dY2, dy2 = obs_info(post.mu_alpha, applied)
    np.testing.assert_allclose(dY2, dY1, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(dy2, dy1, rtol=1e-12, atol=1e-12)


def test_aibo_covariances_spd_and_smaller_than_filtered(aibo_run):
    batch, lo, pose, post = aibo_run
    for C in (post.cov_alpha, post.cov_gamma):
        np.testing.assert_array_equal(C, np.swapaxes(C, 1, 2))
        assert np.linalg.eigvalsh(C).min() > 0
    diff = np.linalg.eigvalsh(post.cov_alpha - post.cov_gamma)
    scale = np.linalg.eigvalsh(post.cov_alpha).max(axis=1)
    assert (diff.min(axis=1) >= -1e-9 * scale).all()
    assert np.trace(post.cov_gamma[:-1], axis1=1, axis2=2).sum() < 0.8 * np.trace(post.cov_alpha[:-1], axis1=1, axis2=2).sum()


def test_aibo_smoothed_closer_to_truth(aibo_run):
    batch, lo, pose, post = aibo_run
    ea = np.linalg.norm(post.mu_alpha[:, :2] - pose[:, :2], axis=1).mean()
    eg = np.linalg.norm(post.mu_gamma[:, :2] - pose[:, :2], axis=1).mean()
    ha = np.abs(post.mu_alpha[:, 2] - pose[:, 2]).mean()
    hg = np.abs(post.mu_gamma[:, 2] - pose[:, 2]).mean()
    assert eg < 0.9 * ea and hg < 0.9 * ha
    # the posterior covers the truth: normalized squared errors average about 3
    e = post.mu_gamma - pose
    nees = np.einsum("pi,pij,pj->p", e, np.linalg.inv(post.cov_gamma), e).mean()
    assert 1.5 < nees < 5.0


def test_effects_consistent_model():
    """With offsets, cov scales, per-sighting effects and the inverse basis, the TRUE lowered model
    is consistent (E[mahal2] = 2, NEES ~ 3); the plain model is not."""
    from learners.arrays.lowered import BASIS_INVERSE

    batch, lo, pose, post = truth_run(4, [1500], effects=True, basis=BASIS_INVERSE, max_per_frame=3)
    assert 1.7 < post.mahal2.mean() < 2.3
    e = post.mu_gamma - pose
    assert 1.5 < np.einsum("pi,pij,pj->p", e, np.linalg.inv(post.cov_gamma), e).mean() < 5.0
    plain = replace(lo, size_scale=np.ones_like(lo.size_scale), size_offset=np.zeros_like(lo.size_offset),
                    bearing_offset=np.zeros_like(lo.bearing_offset))  # fmt: skip
    assert sm.smooth(plain, batch).mahal2.mean() > 3.0


def test_heading_wrap_many_turns():
    rng = np.random.default_rng(3)
    table = np.array([[1.3, 0.0, 0.1], [0.0, 1.3, -0.08]] * 20)
    batch, lo, pose = simulate(rng, [700], table, seg=350)
    assert pose[:, 2].max() - pose[:, 2].min() > 6 * np.pi  # several full circles
    ang = batch.sight_value[:, 1]
    assert (ang > 3.0).any() and (ang < -3.0).any()  # sightings straddle +-pi
    post = sm.smooth(lo, batch)
    assert np.abs(post.mu_gamma[:, 2] - pose[:, 2]).max() < 0.15  # unwrapped, no 2pi jumps
    # shifting the whole problem by 2pi in heading shifts the means by 2pi, nothing else
    post2 = sm.smooth(replace(lo, init_mean=lo.init_mean + [0, 0, 2 * np.pi]), batch)
    np.testing.assert_allclose(post2.mu_gamma - [0, 0, 2 * np.pi], post.mu_gamma, atol=1e-7)
    np.testing.assert_allclose(post2.cov_gamma, post.cov_gamma, rtol=1e-6, atol=1e-9)
    assert post2.loglik == pytest.approx(post.loglik, rel=1e-9)


def _log_slice(batch, lo, k):
    """Log k of (batch, lo) alone."""
    f0, f1 = int(batch.frame_start[k]), int(batch.frame_start[k + 1])
    s0, s1 = int(batch.sight_start[f0]), int(batch.sight_start[f1])
    b = replace(batch, frame_start=np.array([0, f1 - f0]), actions=batch.actions[f0:f1],
                sight_start=batch.sight_start[f0:f1 + 1] - s0, sight_landmark=batch.sight_landmark[s0:s1],
                sight_xy=batch.sight_xy[s0:s1], sight_value=batch.sight_value[s0:s1], used=batch.used[s0:s1])  # fmt: skip
    lk = replace(lo, disp=lo.disp[f0:f1], offset=lo.offset[f0:f1], cov_scale=lo.cov_scale[f0:f1], cov_sd=lo.cov_sd[f0:f1],
                 size_scale=lo.size_scale[s0:s1], size_offset=lo.size_offset[s0:s1],
                 size_var_factor=lo.size_var_factor[s0:s1], bearing_offset=lo.bearing_offset[s0:s1],
                 init_mean=lo.init_mean[k:k + 1], init_cov=lo.init_cov[k:k + 1])  # fmt: skip
    return b, lk, (f0, f1), (s0, s1)


def test_several_logs_equal_each_alone():
    rng = np.random.default_rng(5)
    batch, lo, pose = simulate(rng, [250, 1, 57, 0, 400], true_table(rng), effects=True, max_per_frame=2)
    post = sm.smooth(lo, batch)
    ll = 0.0
    for k in range(batch.n_logs):
        b, lk, (f0, f1), (s0, s1) = _log_slice(batch, lo, k)
        one = sm.smooth(lk, b)
        ps = slice(batch.pose_start[k], batch.pose_start[k + 1])
        for name, sl in [("mu_alpha", ps), ("cov_alpha", ps), ("mu_gamma", ps), ("cov_gamma", ps),
                         ("info_delta", slice(f0, f1)), ("vec_delta", slice(f0, f1)), ("mahal2", slice(s0, s1))]:
            np.testing.assert_array_equal(getattr(post, name)[sl], getattr(one, name), err_msg=f"log {k} {name}")
        np.testing.assert_array_equal(post.mu_alpha[ps][0], lo.init_mean[k])
        ll += one.loglik
    assert post.loglik == pytest.approx(ll, rel=1e-12)


def test_gating_outlier():
    batch, lo, pose, _ = truth_run(11, [600], max_per_frame=2)
    j = int(np.flatnonzero(np.diff(batch.sight_start) == 2)[40])  # a frame with two sightings
    q = int(batch.sight_start[j])  # its first
    val = batch.sight_value.copy()
    val[q, 0] += 60.0  # gross size outlier
    val[q, 1] = geo.wrap(val[q, 1] + 2.0)
    batch = replace(batch, sight_value=val)
    plain = sm.smooth(lo, batch)
    assert plain.mahal2[q] > 1000.0
    gated = sm.smooth(lo, batch, gate=13.8)
    assert gated.mahal2[q] > 13.8 and gated.mahal2[q + 1] < 13.8  # the other sighting of the frame is applied
    pruned = batch.used & (gated.mahal2 > 13.8)
    assert pruned[q]
    removed = sm.smooth(lo, batch.with_used(batch.used & ~pruned))
    for name in ("mu_alpha", "cov_alpha", "mu_gamma", "cov_gamma", "info_delta", "vec_delta"):
        np.testing.assert_allclose(getattr(gated, name), getattr(removed, name), rtol=1e-12, atol=1e-12, err_msg=name)
    assert gated.loglik == pytest.approx(removed.loglik, rel=1e-12)
    keep = ~pruned
    np.testing.assert_array_equal(gated.mahal2[keep], removed.mahal2[keep])
    assert np.abs(plain.mu_gamma - gated.mu_gamma).max() > 1.0  # the outlier did distort the ungated posterior


def test_non_finite_raises_naming_log_and_frame():
    rng = np.random.default_rng(2)
    batch, lo, pose = simulate(rng, [50, 60], true_table(rng))
    q = int(np.flatnonzero(batch.sight_frame >= 50)[3])
    j = int(batch.sight_frame[q]) - 50
    val = batch.sight_value.copy()
    val[q, 0] = np.nan
    with pytest.raises(FloatingPointError, match=rf"log 1, frame {j}\b"):
        sm.smooth(lo, replace(batch, sight_value=val))
    with pytest.raises(ValueError):
        sm.smooth(replace(lo, init_mean=lo.init_mean[:1], init_cov=lo.init_cov[:1]), batch)
