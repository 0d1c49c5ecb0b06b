"""The compiled E-step (learners.em.kernels) against the NumPy reference, to 1e-9.

Synthetic batches are simulated here with the aibo motion/observation model (no env package):
several logs of different lengths, gaps of hundreds of frames without sightings, bearings near
+-pi, headings that wind several turns, gross outliers (with and without the gate), and
zero / nonzero action models.

Two references: the project's ``learners.em.smoother`` / ``action_mstep`` (skipped while absent)
and a short spec-literal transcription of docs/em-math.md below (np.linalg, one frame at a time).
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from learners.em.data import Batch
from learners.em.params import N_ACTIONS, ActionModel, InitialState, Params, SensorModel, paper_start
from learners.em.kernels import smooth_compiled

GATE = 13.8
DT = 1.0 / 30.0
BEACONS = np.array([[-2900.0, -2000.0], [0.0, -2000.0], [2900.0, -2000.0],
                    [-2900.0, 2000.0], [0.0, 2000.0], [2900.0, 2000.0]])  # fmt: skip
TRUE_SIGMA = (0.8, 0.03)  # px, rad


def _true_height(d):
    return 57000.0 / d


def _true_coef():
    d = np.linspace(900.0, 5500.0, 200)
    return np.polynomial.polynomial.polyfit(d, _true_height(d), 3)


def _wrap(a):
    return a - 2 * np.pi * np.ceil((a - np.pi) / (2 * np.pi))


def _rot(th):
    c, s = math.cos(th), math.sin(th)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _true_disp(rng):
    """(40, 3) per-frame displacements: up to ~22 mm/frame forward, 8 sideways, -0.05..0.15 rad/frame."""
    d = np.zeros((N_ACTIONS, 3))
    d[:, 0] = rng.uniform(-12.0, 22.0, N_ACTIONS)
    d[:, 1] = rng.uniform(-8.0, 8.0, N_ACTIONS)
    d[:, 2] = rng.uniform(-0.05, 0.15, N_ACTIONS)  # biased: the heading winds several turns
    d[0] = 0.0
    return d


def _simulate_log(rng, n, disp, gaps=(), outliers=0, behind=0.1, seg=30):
    """One log: actions held for ``seg`` frames, steered to stay on the field (|x| < 2200, |y| < 1400)."""
    pose = np.array([rng.uniform(-800, 800), rng.uniform(-500, 500), rng.uniform(-np.pi, np.pi)])
    start = pose.copy()
    noise_std = np.array([2.0, 2.0, 0.01])
    actions = np.empty(n, np.int64)
    obs = np.full((n, 2), np.nan)
    bxy = np.full((n, 2), np.nan)
    a = 0
    for i in range(n):
        if i % seg == 0:
            # pick among random candidate actions the one keeping the robot nearest the centre
            cand = rng.integers(0, N_ACTIONS, 8)
            best, best_d = cand[0], np.inf
            for c in cand:
                p = pose.copy()
                for _ in range(seg):
                    p = p + _rot(p[2]) @ disp[c]
                dd = abs(p[0]) / 2200 + abs(p[1]) / 1400
                if dd < best_d:
                    best, best_d = c, dd
            a = int(best)
        actions[i] = a
        pose = pose + _rot(pose[2]) @ (disp[a] + rng.normal(0, noise_std))
        if rng.random() < 0.7:
            if rng.random() < behind:  # the beacon most nearly behind the robot: bearing near +-pi
                brg = _wrap(np.arctan2(BEACONS[:, 1] - pose[1], BEACONS[:, 0] - pose[0]) - pose[2])
                b = int(np.argmax(np.abs(brg)))
            else:
                b = int(rng.integers(0, len(BEACONS)))
            dx, dy = BEACONS[b] - pose[:2]
            d = math.hypot(dx, dy)
            bxy[i] = BEACONS[b]
            obs[i, 0] = _true_height(d) + rng.normal(0, TRUE_SIGMA[0])
            obs[i, 1] = _wrap(math.atan2(dy, dx) - pose[2] + rng.normal(0, TRUE_SIGMA[1]))
    for g0, g1 in gaps:
        obs[g0:g1] = np.nan
        bxy[g0:g1] = np.nan
    seen = np.flatnonzero(~np.isnan(obs[:, 0]))
    outliers = min(outliers, len(seen))
    if outliers:
        bad = rng.choice(seen, outliers, replace=False)
        obs[bad, 0] += rng.choice([-1, 1], outliers) * rng.uniform(20, 40, outliers)
        obs[bad[::2], 1] = _wrap(obs[bad[::2], 1] + rng.uniform(1.5, 3.0, len(bad[::2])))
    return actions, obs, bxy, start


def _batch(rng, lengths, disp, gaps=None, outliers=0):
    parts = []
    for k, n in enumerate(lengths):
        parts.append(_simulate_log(rng, n, disp, gaps=(gaps[k] if gaps else ()), outliers=outliers))
    actions = np.concatenate([p[0] for p in parts])
    obs = np.concatenate([p[1] for p in parts])
    bxy = np.concatenate([p[2] for p in parts])
    frame_start = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    starts = [p[3] for p in parts]
    return Batch(actions, obs, bxy, ~np.isnan(obs).any(axis=1), frame_start, DT), starts


def _params(rng, disp, starts, zero_actions=False, learned_cov=False):
    """Model near the truth; log k's start belief near its true start, heading offset by 2 pi k."""
    if zero_actions:
        d = np.zeros_like(disp)
    else:
        d = disp * (1 + 0.05 * rng.standard_normal(disp.shape)) + 0.3 * rng.standard_normal(disp.shape) * [1, 1, 0.01]
    cov = np.diag([10.0**2, 10.0**2, 0.1**2])
    if learned_cov:
        A = rng.standard_normal((3, 3)) * [3.0, 3.0, 0.01]
        cov = np.diag([4.0, 4.0, 1e-4]) + A @ A.T
    coef = _true_coef() * (1 + 0.002 * rng.standard_normal(4))
    init = tuple(
        InitialState(st + rng.normal(0, [50.0, 50.0, 0.05]) + [0.0, 0.0, 2 * np.pi * k],
                     np.diag([100.0**2, 100.0**2, 0.1**2]))  # fmt: skip
        for k, st in enumerate(starts)
    )
    return Params(ActionModel(d, cov, DT), SensorModel(coef, 1.0, 0.04), init)


# ----------------------------------------------------------------------------------------------
# spec-literal transcription of docs/em-math.md (independent of both implementations)
# ----------------------------------------------------------------------------------------------


def _g(mu, u):
    th = mu[2]
    c, s = math.cos(th), math.sin(th)
    F = np.eye(3)
    F[0, 2] = -s * u[0] - c * u[1]
    F[1, 2] = c * u[0] - s * u[1]
    return mu + _rot(th) @ u, F, _rot(th)


def _h(mu, b, coef):
    dx, dy = b[0] - mu[0], b[1] - mu[1]
    q = dx * dx + dy * dy
    d = math.sqrt(q)
    f = np.polynomial.polynomial.polyval(d, coef)
    fp = np.polynomial.polynomial.polyval(d, np.polynomial.polynomial.polyder(coef))
    H = np.array([[-fp * dx / d, -fp * dy / d, 0.0], [dy / q, -dx / q, -1.0]])
    return np.array([f, math.atan2(dy, dx) - mu[2]]), H


def _spec_smooth(params, batch, gate=None):
    n, S = batch.n_frames, batch.n_logs
    P_ = n + S
    out = dict(mu_alpha=np.zeros((P_, 3)), cov_alpha=np.zeros((P_, 3, 3)), mu_gamma=np.zeros((P_, 3)),
               cov_gamma=np.zeros((P_, 3, 3)), info_delta=np.zeros((n, 3, 3)), vec_delta=np.zeros((n, 3)),
               mahal2=np.full(n, np.nan))  # fmt: skip
    Ro = np.diag([params.sensor.sigma_height**2, params.sensor.sigma_angle**2])
    Roi = np.linalg.inv(Ro)
    Sig = params.action.cov
    coef = params.sensor.coef
    ll = 0.0
    skip = np.zeros(n, bool)
    for k in range(S):
        f0, f1 = batch.frame_start[k], batch.frame_start[k + 1]
        ps = f0 + k
        mu, P = params.init[k].mean.copy(), params.init[k].cov.copy()
        out["mu_alpha"][ps], out["cov_alpha"][ps] = mu, P
        for i in range(f0, f1):
            g, F, R = _g(mu, params.action.disp[batch.actions[i]])
            mu, P = g, F @ P @ F.T + R @ Sig @ R.T
            if batch.used[i]:
                h, H = _h(mu, batch.beacon_xy[i], coef)
                v = batch.obs[i] - h
                v[1] = _wrap(v[1])
                Sm = H @ P @ H.T + Ro
                m2 = v @ np.linalg.solve(Sm, v)
                out["mahal2"][i] = m2
                if gate is not None and m2 > gate:
                    skip[i] = True
                else:
                    ll += -0.5 * (m2 + np.log(np.linalg.det(Sm)) + 2 * np.log(2 * np.pi))
                    K = P @ H.T @ np.linalg.inv(Sm)
                    mu = mu + K @ v
                    IKH = np.eye(3) - K @ H
                    P = IKH @ P @ IKH.T + K @ Ro @ K.T
                    P = 0.5 * (P + P.T)
            out["mu_alpha"][i + k + 1], out["cov_alpha"][i + k + 1] = mu, P
        Y, y = np.zeros((3, 3)), np.zeros(3)
        for i in range(f1 - 1, f0 - 1, -1):
            p = i + k
            for q_, (YY, yy) in ((p + 1, (Y, y)),):
                A, ma = out["cov_alpha"][q_], out["mu_alpha"][q_]
                M = np.linalg.inv(np.eye(3) + YY @ A)
                out["mu_gamma"][q_] = ma + A @ M @ (yy - YY @ ma)
                C = A - A @ M @ YY @ A
                out["cov_gamma"][q_] = 0.5 * (C + C.T)
            if batch.used[i] and not skip[i]:
                ma = out["mu_alpha"][p + 1]
                h, H = _h(ma, batch.beacon_xy[i], coef)
                v = batch.obs[i] - h
                v[1] = _wrap(v[1])
                Y = Y + H.T @ Roi @ H
                y = y + H.T @ Roi @ (v + H @ ma)
            out["info_delta"][i], out["vec_delta"][i] = Y, y
            ma = out["mu_alpha"][p]
            g, F, R = _g(ma, params.action.disp[batch.actions[i]])
            c = g - F @ ma
            Q = R @ Sig @ R.T
            B = np.linalg.inv(np.eye(3) + Y @ Q)
            Yt, yt = B @ Y, B @ y
            Y = F.T @ Yt @ F
            Y = 0.5 * (Y + Y.T)
            y = F.T @ (yt - Yt @ c)
        A, ma = out["cov_alpha"][ps], out["mu_alpha"][ps]
        M = np.linalg.inv(np.eye(3) + Y @ A)
        out["mu_gamma"][ps] = ma + A @ M @ (y - Y @ ma)
        C = A - A @ M @ Y @ A
        out["cov_gamma"][ps] = 0.5 * (C + C.T)
    out["loglik"] = ll
    return out


def _spec_action(params, batch, post):
    n = batch.n_frames
    ms, cs = np.zeros((n, 3)), np.zeros((n, 3, 3))
    f2p = batch.frame_to_pose
    Si = np.linalg.inv(params.action.cov)
    for i in range(n):
        p = f2p[i]
        g0, g1 = post["mu_gamma"][p], post["mu_gamma"][p + 1]
        th = g0[2]
        c, s = math.cos(th), math.sin(th)
        dx, dy = g1[0] - g0[0], g1[1] - g0[1]
        d = np.array([c * dx + s * dy, -s * dx + c * dy, g1[2] - g0[2]])
        L2 = _rot(-th)
        L1 = -L2.copy()
        L1[:, 2] = [-s * dx + c * dy, -c * dx - s * dy, -1.0]
        m = d - L1 @ g0 - L2 @ g1
        L2i = np.linalg.inv(L2)
        Yp = L2i.T @ post["info_delta"][i] @ L2i
        yp = L2i.T @ post["vec_delta"][i]
        P1 = L1 @ post["cov_alpha"][p] @ L1.T
        m1 = L1 @ post["mu_alpha"][p] + m
        B = np.linalg.inv(np.eye(3) + Yp @ P1)
        Yd, yd = B @ Yp, B @ (yp + Yp @ m1)
        mh = params.action.disp[batch.actions[i]]
        C = np.linalg.inv(Si + Yd)
        ms[i] = mh + C @ (yd - Yd @ mh)
        cs[i] = C
    return ms, cs


# ----------------------------------------------------------------------------------------------
# comparison helpers
# ----------------------------------------------------------------------------------------------

TOL = 1e-9


def _close_vec(name, a, b, tol=TOL):
    """Per-component scale: |a - b| <= tol * max(1e-300, max |b[:, j]|) plus tol * |b| (relative)."""
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape, name
    scale = np.max(np.abs(b), axis=0, keepdims=True)
    err = np.abs(a - b)
    ok = err <= tol * scale + tol * np.abs(b)
    assert ok.all(), f"{name}: max err {err.max():.3e}, at {np.unravel_index(np.argmax(err - tol * scale), err.shape)}"


def _close_mat(name, a, b, tol=TOL):
    """Matrices compared on the scale sqrt(max|b_rr| max|b_cc|) of their own diagonals."""
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape, name
    dmax = np.max(np.abs(np.diagonal(b, axis1=1, axis2=2)), axis=0)
    scale = np.sqrt(np.outer(dmax, dmax))[None]
    err = np.abs(a - b)
    ok = err <= tol * scale + tol * np.abs(b)
    rel = err / np.maximum(scale, 1e-300)
    assert ok.all(), f"{name}: max scaled err {rel.max():.3e} at {np.unravel_index(np.argmax(rel), err.shape)}"


def _get(post, key):
    return post[key] if isinstance(post, dict) else getattr(post, key)


def _compare_posteriors(got, ref, tol=TOL):
    for key in ("mu_alpha", "mu_gamma", "vec_delta"):
        _close_vec(key, _get(got, key), _get(ref, key), tol)
    for key in ("cov_alpha", "cov_gamma", "info_delta"):
        _close_mat(key, _get(got, key), _get(ref, key), tol)
    m_got, m_ref = _get(got, "mahal2"), _get(ref, "mahal2")
    np.testing.assert_array_equal(np.isnan(m_got), np.isnan(m_ref))
    fin = ~np.isnan(m_ref)
    np.testing.assert_allclose(m_got[fin], m_ref[fin], rtol=tol, atol=tol)
    assert abs(_get(got, "loglik") - _get(ref, "loglik")) <= tol * max(1.0, abs(_get(ref, "loglik")))


# ----------------------------------------------------------------------------------------------
# cases
# ----------------------------------------------------------------------------------------------


@functools.lru_cache(maxsize=None)
def _case(name):
    """(params, batch) for a named case; deterministic."""
    rng = np.random.default_rng(sum(map(ord, name)))
    disp = _true_disp(rng)
    if name == "multi":  # three logs of different lengths, long gaps, outliers
        lengths = [900, 350, 1300]
        gaps = [[(100, 400)], [], [(200, 450), (800, 1100)]]
        batch, starts = _batch(rng, lengths, disp, gaps=gaps, outliers=12)
        params = _params(rng, disp, starts)
    elif name == "zero_actions":  # the paper's start: all displacements zero
        batch, starts = _batch(rng, [700, 500], disp, gaps=[[(50, 300)], [(0, 120)]], outliers=6)
        params = _params(rng, disp, starts, zero_actions=True)
    elif name == "learned_cov":  # non-diagonal Sigma_A, one log, tiny log of 1 frame and 0 frames
        batch, starts = _batch(rng, [800, 1, 0, 40], disp, gaps=[[(300, 650)], [], [], [(0, 40)]], outliers=8)
        params = _params(rng, disp, starts, learned_cov=True)
    elif name == "paper_start":  # the paper's start (zero actions, poor sensor line), default start pose
        _, batch = _case("multi")
        params = paper_start(DT, batch.n_logs)
    else:
        raise KeyError(name)
    return params, batch


CASES = ["multi", "zero_actions", "learned_cov", "paper_start"]


def _batch_props(batch, post, gate):
    """Sanity on the synthetic data itself: it covers what the brief asks for."""
    used = batch.used
    ps = batch.pose_start
    turns = [np.ptp(post.mu_gamma[ps[k] : ps[k + 1], 2]) / (2 * np.pi) for k in range(batch.n_logs) if ps[k + 1] > ps[k] + 1]
    return dict(
        n_used=int(used.sum()),
        near_pi=int((np.abs(batch.obs[used, 1]) > 3.0).sum()),
        turns=float(min(turns)),
        gated=int((used & (post.mahal2 > GATE)).sum()),
    )


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("gate", [None, GATE])
def test_smooth_matches_spec_transcription(case, gate):
    params, batch = _case(case)
    got = smooth_compiled(params, batch, gate)
    ref = _spec_smooth(params, batch, gate)
    _compare_posteriors(got, ref)
    # the end pose of each log: gamma == alpha; NaN mahal2 exactly where no used sighting
    last = batch.pose_start[1:] - 1
    np.testing.assert_array_equal(got.mu_gamma[last], got.mu_alpha[last])
    np.testing.assert_array_equal(np.isnan(got.mahal2), ~batch.used)
    # the reference action statistics (fed to the compiled M-step tests below) equal the spec's
    from learners.em.action_mstep import action_statistics

    ms, cs = action_statistics(params, batch, got)
    ms_ref, cs_ref = _spec_action(params, batch, ref)
    _close_vec("mu_star", ms, ms_ref)
    _close_mat("C_star", cs, cs_ref)


def test_synthetic_cases_cover_the_brief():
    params, batch = _case("multi")
    post = smooth_compiled(params, batch, None)
    props = _batch_props(batch, post, GATE)
    assert props["near_pi"] >= 20, props
    assert props["turns"] >= 3, props
    assert props["gated"] >= 6, props
    assert len(np.unique(np.diff(batch.frame_start))) == 3
    # gating changes the answer: fewer likelihood terms, different means
    gated = smooth_compiled(params, batch, GATE)
    assert gated.loglik > post.loglik
    assert not np.allclose(gated.mu_gamma, post.mu_gamma)


def _reference_or_skip():
    smoother = pytest.importorskip("learners.em.smoother")
    if not hasattr(smoother, "smooth"):
        pytest.skip("reference smoother.smooth not written yet")
    return smoother


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("gate", [None, GATE])
def test_smooth_matches_numpy_reference(case, gate):
    smoother = _reference_or_skip()
    params, batch = _case(case)
    got = smooth_compiled(params, batch, gate)
    ref = smoother.smooth(params, batch, gate)
    _compare_posteriors(got, ref)


def test_nonfinite_raises_naming_log_and_frame():
    params, batch = _case("multi")
    obs = batch.obs.copy()
    used = batch.used.copy()
    i = int(batch.frame_start[1]) + 77  # log 1, frame 77
    used[i] = True
    obs[i] = np.nan
    bad = Batch(batch.actions, obs, np.where(np.isnan(batch.beacon_xy), 1000.0, batch.beacon_xy), used,
                batch.frame_start, batch.dt)  # fmt: skip
    with pytest.raises(FloatingPointError, match=r"log 1, frame 77"):
        smooth_compiled(params, bad)


# ----------------------------------------------------------------------------------------------
# fused compiled M-step (fit.m_step with estep="compiled") against the NumPy reference path
# ----------------------------------------------------------------------------------------------


def _mstep_pair(params, batch, post, method, learn_noise, seed=7, n_samples=1):
    from learners.em.fit import EMOptions, m_step

    opts = EMOptions(sensor_method=method, learn_motion_noise=learn_noise, n_samples=n_samples)
    ref_opts = EMOptions(sensor_method=method, learn_motion_noise=learn_noise, n_samples=n_samples, estep="numpy")
    rng_c, rng_r = np.random.default_rng(seed), np.random.default_rng(seed)
    got = m_step(params, batch, post, rng_c, opts)
    ref = m_step(params, batch, post, rng_r, ref_opts)
    assert rng_c.bit_generator.state == rng_r.bit_generator.state  # same draws from the generator
    return got, ref


def _assert_params_close(got, ref, tol=TOL):
    _close_vec("disp", got.action.disp, ref.action.disp, tol)
    _close_mat("action cov", got.action.cov[None], ref.action.cov[None], tol)
    assert got.action.dt == ref.action.dt
    c_got, c_ref = np.asarray(got.sensor.coef), np.asarray(ref.sensor.coef)
    assert c_got.shape == c_ref.shape
    # coefficients of powers of d (mm): compare the fitted curves on the distance range, and each
    # coefficient relative to its own size
    np.testing.assert_allclose(c_got, c_ref, rtol=tol, atol=0)
    for name in ("sigma_height", "sigma_angle"):
        np.testing.assert_allclose(getattr(got.sensor, name), getattr(ref.sensor, name), rtol=tol, atol=0)
    np.testing.assert_allclose(got.sensor.distance_range_mm, ref.sensor.distance_range_mm, rtol=tol, atol=0)
    assert len(got.init) == len(ref.init)
    for a, b in zip(got.init, ref.init):
        np.testing.assert_array_equal(a.mean, b.mean)
        np.testing.assert_array_equal(a.cov, b.cov)


def _with_unused_action(params, batch):
    """Params/batch where action 0 and the highest action are never executed (their disp must be kept)."""
    actions = batch.actions.copy()
    n_act = params.action.disp.shape[0]
    actions[actions == 0] = 1
    actions[actions == n_act - 1] = 1
    b = Batch(actions, batch.obs, batch.beacon_xy, batch.used, batch.frame_start, batch.dt)
    disp = np.array(params.action.disp, float)
    disp[0] = [3.0, -1.0, 0.02]
    disp[n_act - 1] = [-2.0, 0.5, -0.01]
    return params.with_(action=ActionModel(disp, params.action.cov, params.action.dt)), b


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("method", ["cubature", "sample"])
@pytest.mark.parametrize("learn_noise", [False, True])
def test_compiled_mstep_matches_numpy_reference(case, method, learn_noise):
    _reference_or_skip()
    params, batch = _case(case)
    params, batch = _with_unused_action(params, batch)
    post = smooth_compiled(params, batch, GATE)
    batch = batch.with_used(batch.used & ~(post.mahal2 > GATE))  # the loop prunes gated sightings
    post = smooth_compiled(params, batch, None)
    got, ref = _mstep_pair(params, batch, post, method, learn_noise)
    _assert_params_close(got, ref)
    n_act = params.action.disp.shape[0]
    np.testing.assert_array_equal(got.action.disp[[0, n_act - 1]], params.action.disp[[0, n_act - 1]])
    if not learn_noise:
        np.testing.assert_array_equal(got.action.cov, params.action.cov)


def test_compiled_mstep_several_samples_and_degrees():
    _reference_or_skip()
    from learners.em.fit import EMOptions, m_step

    params, batch = _case("multi")
    post = smooth_compiled(params, batch, None)
    got, ref = _mstep_pair(params, batch, post, "sample", True, seed=3, n_samples=4)
    _assert_params_close(got, ref)
    for degree in (1, 2, 5):
        for method in ("cubature", "sample"):
            r1, r2 = np.random.default_rng(1), np.random.default_rng(1)
            got = m_step(params, batch, post, r1, EMOptions(sensor_method=method, degree=degree))
            ref = m_step(params, batch, post, r2, EMOptions(sensor_method=method, degree=degree, estep="numpy"))
            _assert_params_close(got, ref)


def test_compiled_mstep_after_em_iterations():
    """A few EM iterations on the paper's start (learned noise), then compiled == reference."""
    _reference_or_skip()
    from learners.em.fit import EMOptions, m_step

    params, batch = _case("paper_start")
    opts = EMOptions(sensor_method="cubature", learn_motion_noise=True, estep="numpy")
    post = smooth_compiled(params, batch, None)
    for it in range(3):
        params = m_step(params, batch, post, np.random.default_rng(it), opts)
        post = smooth_compiled(params, batch, None)
    for method in ("cubature", "sample"):
        got, ref = _mstep_pair(params, batch, post, method, True)
        _assert_params_close(got, ref)


def test_compiled_mstep_errors_like_reference():
    _reference_or_skip()
    from learners.em.fit import EMOptions, m_step

    params, batch = _case("multi")
    post = smooth_compiled(params, batch, None)
    # a smoothed covariance that is not positive definite: FloatingPointError, generator untouched
    frames = np.flatnonzero(batch.used)
    bad_pose = int(batch.frame_to_pose[frames[5]] + 1)
    cov = post.cov_gamma.copy()
    cov[bad_pose] = -np.eye(3)
    bad = type(post)(post.mu_alpha, post.cov_alpha, post.mu_gamma, cov, post.info_delta, post.vec_delta,
                     post.loglik, post.mahal2)  # fmt: skip
    for estep in ("compiled", "numpy"):
        rng = np.random.default_rng(0)
        before = rng.bit_generator.state
        with pytest.raises(FloatingPointError):
            m_step(params, batch, bad, rng, EMOptions(sensor_method="sample", estep=estep))
        assert rng.bit_generator.state == before
    # too few sightings for the polynomial: ValueError on both paths
    few = batch.with_used(batch.used & (np.cumsum(batch.used) <= 3))
    for estep in ("compiled", "numpy"):
        with pytest.raises(ValueError, match="need at least"):
            m_step(params, few, post, np.random.default_rng(0), EMOptions(sensor_method="sample", estep=estep))
