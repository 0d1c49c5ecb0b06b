"""The compiled E-step and M-step statistics (learners.inference.kernels) against the NumPy
reference (learners.inference.reference / action_stats / sensor_stats) and against a short
spec-literal transcription of docs/em-math.md below (np.linalg, one frame and one sighting at a
time), to 1e-9, on the synthetic cases of tests/_synth.py: several logs (of 1 and 0 frames too),
gaps, several sightings per frame, bearings near +-pi, headings winding several turns, outliers
(with and without the gate), offsets, cov scales, per-sighting effects, the inverse-distance basis,
and the plain one-hot table + cubic model.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from learners.arrays.lowered import BASIS_POWER, curve
from learners.inference import action_stats, sensor_stats
from learners.inference.kernels import (
    action_statistics_compiled,
    residual_cov_compiled,
    sensor_update_compiled,
    smooth_compiled,
)
from learners.inference.reference import smooth
from tests._synth import CASES, GATE, case, pinhole_coef, rot3, wrap

# ----------------------------------------------------------------------------------------------
# spec-literal transcription of docs/em-math.md (independent of both implementations)
# ----------------------------------------------------------------------------------------------


def _g(mu, u, o):
    th = mu[2]
    c, s = math.cos(th), math.sin(th)
    F = np.eye(3)
    F[0, 2] = -s * u[0] - c * u[1]
    F[1, 2] = c * u[0] - s * u[1]
    return mu + rot3(th) @ u + o, F, rot3(th)


def _h(lo, q, mu, b):
    dx, dy = b[0] - mu[0], b[1] - mu[1]
    qq = dx * dx + dy * dy
    d = math.sqrt(qq)
    if lo.basis == BASIS_POWER:
        f = np.polynomial.polynomial.polyval(d, lo.coef)
        fp = np.polynomial.polynomial.polyval(d, np.polynomial.polynomial.polyder(lo.coef))
    else:  # f = sum c_k d^-k, f' = sum -k c_k d^(-k-1)
        k = np.arange(len(lo.coef))
        f = float(np.sum(lo.coef * d ** (-k)))
        fp = float(np.sum(-k * lo.coef * d ** (-k - 1.0)))
    sc = lo.size_scale[q]
    H = np.array([[-sc * fp * dx / d, -sc * fp * dy / d, 0.0], [dy / qq, -dx / qq, -1.0]])
    h = np.array([sc * f + lo.size_offset[q], math.atan2(dy, dx) - mu[2] + lo.bearing_offset[q]])
    Ro = np.diag([lo.sigma_size**2 * lo.size_var_factor[q], lo.sigma_bearing**2 * lo.bearing_var_factor[q]])
    return h, H, Ro


def _v(batch, q, h):
    v = batch.sight_value[q] - h
    v[1] = wrap(v[1])
    return v


def _sigma_i(lo, i):
    """Frame i's motion covariance (robot frame): cov_scale_i D_i Sigma_A D_i, D_i = diag(cov_sd[i])."""
    D = np.diag(lo.cov_sd[i])
    return lo.cov_scale[i] * D @ lo.cov @ D


def _whitened_sum(lo, cs):
    """sum_i D_i^-1 C_i D_i^-1 / cov_scale_i of per-frame (N, 3, 3) ``cs``: what the M-step of Sigma_A averages."""
    Di = np.stack([np.diag(1.0 / d) for d in lo.cov_sd])
    return (Di @ cs @ Di / lo.cov_scale[:, None, None]).sum(axis=0)


def _spec_smooth(lo, batch, gate=None):
    n, L = batch.n_frames, batch.n_logs
    P_ = n + L
    out = dict(mu_alpha=np.zeros((P_, 3)), cov_alpha=np.zeros((P_, 3, 3)), mu_gamma=np.zeros((P_, 3)),
               cov_gamma=np.zeros((P_, 3, 3)), info_delta=np.zeros((n, 3, 3)), vec_delta=np.zeros((n, 3)),
               mahal2=np.full(batch.n_sightings, np.nan))  # fmt: skip
    ss = batch.sight_start
    ll = 0.0
    applied = np.zeros(batch.n_sightings, bool)
    for k in range(L):
        f0, f1 = batch.frame_start[k], batch.frame_start[k + 1]
        ps = f0 + k
        mu, P = lo.init_mean[k].copy(), lo.init_cov[k].copy()
        out["mu_alpha"][ps], out["cov_alpha"][ps] = mu, P
        for i in range(f0, f1):
            g, F, R = _g(mu, lo.disp[i], lo.offset[i])
            mu, P = g, F @ P @ F.T + R @ _sigma_i(lo, i) @ R.T
            for q in range(ss[i], ss[i + 1]):
                if not batch.used[q]:
                    continue
                h, H, Ro = _h(lo, q, mu, batch.sight_xy[q])
                v = _v(batch, q, h)
                Sm = H @ P @ H.T + Ro
                m2 = v @ np.linalg.solve(Sm, v)
                out["mahal2"][q] = m2
                if gate is not None and m2 > gate:
                    continue
                applied[q] = True
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
            A, ma = out["cov_alpha"][p + 1], out["mu_alpha"][p + 1]
            M = np.linalg.inv(np.eye(3) + Y @ A)
            out["mu_gamma"][p + 1] = ma + A @ M @ (y - Y @ ma)
            C = A - A @ M @ Y @ A
            out["cov_gamma"][p + 1] = 0.5 * (C + C.T)
            for q in range(ss[i], ss[i + 1]):
                if applied[q]:  # linearized at the frame's final filtered mean
                    h, H, Ro = _h(lo, q, ma, batch.sight_xy[q])
                    Roi = np.linalg.inv(Ro)
                    Y = Y + H.T @ Roi @ H
                    y = y + H.T @ Roi @ (_v(batch, q, h) + H @ ma)
            out["info_delta"][i], out["vec_delta"][i] = Y, y
            ma = out["mu_alpha"][p]
            g, F, R = _g(ma, lo.disp[i], lo.offset[i])
            c = g - F @ ma
            Q = R @ _sigma_i(lo, i) @ R.T
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


def _spec_action(lo, batch, post):
    """mu*_i, C*_i for d = R(-theta_p)(s_{p+1} - s_p - offset_i), prior N(disp_i, Sigma_i)."""
    n = batch.n_frames
    ms, cs = np.zeros((n, 3)), np.zeros((n, 3, 3))
    f2p = batch.frame_to_pose
    for i in range(n):
        p = f2p[i]
        o = lo.offset[i]
        g0, g1 = post["mu_gamma"][p], post["mu_gamma"][p + 1] - o
        th = g0[2]
        c, s = math.cos(th), math.sin(th)
        dx, dy = g1[0] - g0[0], g1[1] - g0[1]
        d = np.array([c * dx + s * dy, -s * dx + c * dy, g1[2] - g0[2]])
        L2 = rot3(-th)
        L1 = -L2.copy()
        L1[:, 2] = [-s * dx + c * dy, -c * dx - s * dy, -1.0]
        m = d - L1 @ g0 - L2 @ g1
        # delta on s'' = s' - o: information (Y, y - Y o)
        Yo, yo = post["info_delta"][i], post["vec_delta"][i] - post["info_delta"][i] @ o
        L2i = np.linalg.inv(L2)
        Yp = L2i.T @ Yo @ L2i
        yp = L2i.T @ yo
        P1 = L1 @ post["cov_alpha"][p] @ L1.T
        m1 = L1 @ post["mu_alpha"][p] + m
        B = np.linalg.inv(np.eye(3) + Yp @ P1)
        Yd, yd = B @ Yp, B @ (yp + Yp @ m1)
        mh = lo.disp[i]
        C = np.linalg.inv(np.linalg.inv(_sigma_i(lo, i)) + Yd)
        ms[i] = mh + C @ (yd - Yd @ mh)
        cs[i] = C
    return ms, cs


# ----------------------------------------------------------------------------------------------
# comparison helpers
# ----------------------------------------------------------------------------------------------

TOL = 1e-9


def _close_vec(name, a, b, tol=TOL):
    """Per-component scale: |a - b| <= tol * max |b[:, j]| + tol * |b|."""
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape, name
    scale = np.max(np.abs(b), axis=0, keepdims=True) if len(b) else 0.0
    err = np.abs(a - b)
    ok = err <= tol * scale + tol * np.abs(b)
    assert ok.all(), f"{name}: max err {err.max():.3e}"


def _close_mat(name, a, b, tol=TOL):
    """Matrices compared on the scale sqrt(max|b_rr| max|b_cc|) of their own diagonals."""
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape, name
    if not len(b):
        return
    dmax = np.max(np.abs(np.diagonal(b, axis1=1, axis2=2)), axis=0)
    scale = np.sqrt(np.outer(dmax, dmax))[None]
    err = np.abs(a - b)
    ok = err <= tol * scale + tol * np.abs(b)
    assert ok.all(), f"{name}: max scaled err {(err / np.maximum(scale, 1e-300)).max():.3e}"


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
# E-step
# ----------------------------------------------------------------------------------------------


def test_synthetic_cases_cover_the_brief():
    props = {}
    for name in CASES:
        lo, batch, _ = case(name)
        post = smooth_compiled(lo, batch, None)
        per = np.diff(batch.sight_start)
        ps = batch.pose_start
        turns = [np.ptp(post.mu_gamma[ps[k]: ps[k + 1], 2]) / (2 * np.pi) for k in range(batch.n_logs)
                 if ps[k + 1] > ps[k] + 1]  # fmt: skip
        props[name] = dict(max_per=int(per.max()), none=int((per == 0).sum()), turns=min(turns),
                           near_pi=int((np.abs(batch.sight_value[:, 1]) > 3.0).sum()),
                           gated=int((post.mahal2 > GATE).sum()), offset=float(np.abs(lo.offset).max()),
                           scale=float(np.ptp(lo.cov_scale)), sd=float(np.ptp(lo.cov_sd)), vf=float(np.ptp(lo.size_var_factor)),
                           bo=float(np.abs(lo.bearing_offset).max()), basis=lo.basis)  # fmt: skip
    assert props["multi"]["max_per"] == 1 and props["multi"]["offset"] == 0 and props["multi"]["scale"] == 0
    for name in ("several", "effects"):
        assert props[name]["max_per"] == 3, props[name]
    for name in ("effects", "inverse"):
        p = props[name]
        assert p["offset"] > 0 and p["scale"] > 0.5 and p["sd"] > 1 and p["vf"] > 1 and p["bo"] > 0.05, p
    assert props["inverse"]["basis"] == 1
    for name, p in props.items():
        assert p["none"] > 100 and p["gated"] >= 3, (name, p)
    assert props["multi"]["near_pi"] >= 20 and props["multi"]["turns"] >= 3, props["multi"]


@pytest.mark.parametrize("name", CASES)
@pytest.mark.parametrize("gate", [None, GATE])
def test_smooth_matches_spec_and_reference(name, gate):
    lo, batch, _ = case(name)
    got = smooth_compiled(lo, batch, gate)
    spec = _spec_smooth(lo, batch, gate)
    _compare_posteriors(got, spec)
    _compare_posteriors(smooth(lo, batch, gate), spec)
    # the end pose of each log: gamma == alpha; NaN mahal2 exactly where the sighting is not used
    last = batch.pose_start[1:] - 1
    np.testing.assert_array_equal(got.mu_gamma[last], got.mu_alpha[last])
    np.testing.assert_array_equal(np.isnan(got.mahal2), ~batch.used)


def test_kernel_inputs_are_named_with_their_shapes():
    """The kernels read their inputs by name (FrameInputs, SightingInputs): each field has the shape its
    comment documents, so a field wired to the wrong array of the lowered model fails here."""
    from learners.inference.kernels.arguments import kernel_inputs
    from learners.inference.kernels.estep import innovations_compiled

    lo, batch, _ = case("multi")
    n, n_s, n_logs = batch.n_frames, batch.n_sightings, batch.n_logs
    assert n_logs > 1
    fr, si = kernel_inputs(lo, batch, GATE)
    shapes = {"frame_start": (n_logs + 1,), "disp": (n, 3), "offset": (n, 3), "cov_scale": (n,), "sig_a": (3, 3),
              "init_mean": (n_logs, 3), "init_cov": (n_logs, 3, 3), "sight_start": (n + 1,), "xy": (n_s, 2),
              "value": (n_s, 2), "used": (n_s,), "size_scale": (n_s,), "size_offset": (n_s,),
              "size_var_factor": (n_s,), "bearing_offset": (n_s,), "bearing_var_factor": (n_s,)}
    for group in (fr, si):
        for name, value in group._asdict().items():
            if name in shapes:
                assert value.shape == shapes[name], name
                assert value.flags.c_contiguous, name
    assert set(shapes) <= set(fr._fields) | set(si._fields)
    np.testing.assert_array_equal(fr.disp, lo.disp)
    np.testing.assert_array_equal(si.value, batch.sight_value)
    assert si.use_gate and si.gate == GATE
    assert si.var_s == lo.sigma_size**2 and si.var_b == lo.sigma_bearing**2
    _, none = kernel_inputs(lo, batch, None)
    assert not none.use_gate and none.gate == np.inf
    # the forward pass alone (innovations) gives the smoother's log-likelihood
    assert innovations_compiled(lo, batch)[0] == pytest.approx(smooth_compiled(lo, batch).loglik, rel=1e-12)


def test_the_forward_pass_alone_keeps_nothing_per_frame():
    """``innovations_compiled`` stores no per-pose beliefs, cos/sin or per-frame information (was 208 bytes per
    frame of scratch, 208 MB at 1,000,000 frames): only the per-sighting mahal2 (8 bytes each); its log-likelihood
    is the smoother's bit for bit, over several logs."""
    from learners.inference.kernels import release_scratch
    from learners.inference.kernels.estep import innovations_compiled

    lo, batch, _ = case("multi")
    release_scratch()
    ll, innov = innovations_compiled(lo, batch)
    assert release_scratch() <= 8 * batch.n_sightings + 1024
    assert ll == smooth_compiled(lo, batch).loglik
    assert innov.shape == (batch.n_sightings, 5) and np.isfinite(innov[batch.used]).all()


def test_gating_and_effects_change_the_answer():
    lo, batch, _ = case("effects")
    post = smooth_compiled(lo, batch, None)
    gated = smooth_compiled(lo, batch, GATE)
    assert gated.loglik > post.loglik and not np.allclose(gated.mu_gamma, post.mu_gamma)
    # gating == pruning the gated sightings
    pruned = smooth_compiled(lo, batch.with_used(batch.used & ~(gated.mahal2 > GATE)), None)
    _compare_posteriors(pruned, _as_dict(gated, keep=~(gated.mahal2 > GATE)))
    # each lowered array is read: plain values instead change the posterior and the likelihood
    for field, plain in (("offset", np.zeros_like(lo.offset)), ("cov_scale", np.ones_like(lo.cov_scale)),
                         ("cov_sd", np.ones_like(lo.cov_sd)),
                         ("size_scale", np.ones_like(lo.size_scale)), ("size_offset", np.zeros_like(lo.size_offset)),
                         ("size_var_factor", np.ones_like(lo.size_var_factor)),
                         ("bearing_offset", np.zeros_like(lo.bearing_offset))):  # fmt: skip
        other = smooth_compiled(replace(lo, **{field: plain}), batch, None)
        assert np.abs(other.mu_gamma - post.mu_gamma).max() > 1e-3 and abs(other.loglik - post.loglik) > 1e-3, field
    # the true effects fit the data better than none at all
    assert post.loglik > smooth_compiled(replace(lo, size_scale=np.ones_like(lo.size_scale),
                                                 size_offset=np.zeros_like(lo.size_offset)), batch).loglik + 100


def _as_dict(post, keep):
    d = {k: getattr(post, k) for k in ("mu_alpha", "cov_alpha", "mu_gamma", "cov_gamma", "info_delta", "vec_delta",
                                       "loglik")}  # fmt: skip
    d["mahal2"] = np.where(keep, post.mahal2, np.nan)
    return d


def test_sightings_are_sequential_updates():
    """Two sightings of one frame applied one after the other (re-linearized) != the order-free
    batch update, and the order matters only at the linearization level (small but non-zero)."""
    lo, batch, _ = case("several")
    post = smooth_compiled(lo, batch, None)
    i = int(np.flatnonzero(np.diff(batch.sight_start) >= 2)[5])
    a, b = batch.sight_start[i], batch.sight_start[i] + 1
    perm = np.arange(batch.n_sightings)
    perm[a], perm[b] = b, a
    sw = replace(batch, sight_landmark=batch.sight_landmark[perm], sight_xy=batch.sight_xy[perm],
                 sight_value=batch.sight_value[perm], used=batch.used[perm])  # fmt: skip
    lo_sw = replace(lo, size_scale=lo.size_scale[perm], size_offset=lo.size_offset[perm],
                    size_var_factor=lo.size_var_factor[perm], bearing_offset=lo.bearing_offset[perm])  # fmt: skip
    post_sw = smooth_compiled(lo_sw, sw, None)
    p = batch.frame_to_pose[i] + 1
    diff = np.abs(post_sw.mu_alpha[p] - post.mu_alpha[p]).max()
    assert 0.0 < diff < 1.0  # mm: linearization differences only
    _compare_posteriors(post_sw, _spec_smooth(lo_sw, sw))


def test_nonfinite_raises_naming_log_and_frame():
    lo, batch, _ = case("multi")
    i = int(batch.frame_start[1]) + 77  # log 1, frame 77
    q = int(np.flatnonzero(batch.sight_frame >= i)[0])
    j = int(batch.sight_frame[q]) - int(batch.frame_start[1])
    val = batch.sight_value.copy()
    val[q, 0] = np.nan
    with pytest.raises(FloatingPointError, match=rf"log 1, frame {j}\b"):
        smooth_compiled(lo, replace(batch, sight_value=val))
    with pytest.raises(FloatingPointError, match=rf"log 1, frame {j}\b"):
        smooth(lo, replace(batch, sight_value=val))


def test_buffer_reuse_gives_the_same_numbers():
    lo, batch, _ = case("several")
    a = smooth_compiled(lo, batch, GATE)
    ref = {k: getattr(a, k).copy() for k in ("mu_gamma", "cov_gamma", "info_delta", "mahal2")}
    other = replace(lo, disp=lo.disp * 1.1)
    b = smooth_compiled(other, batch, None, out=a)
    c = smooth_compiled(lo, batch, GATE, out=b)
    assert c.mu_gamma is a.mu_gamma
    for k, v in ref.items():
        np.testing.assert_array_equal(getattr(c, k), v)


# ----------------------------------------------------------------------------------------------
# M-step statistics
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", CASES)
def test_action_statistics_match_spec_and_reference(name):
    lo, batch, _ = case(name)
    post = smooth_compiled(lo, batch, GATE)
    spec_post = {k: getattr(post, k) for k in ("mu_alpha", "cov_alpha", "mu_gamma", "info_delta", "vec_delta")}
    ms_spec, cs_spec = _spec_action(lo, batch, spec_post)
    C_spec = _whitened_sum(lo, cs_spec)
    ms_ref, C_ref = action_stats.action_statistics(lo, batch, post, True)
    ms_got, C_got = action_statistics_compiled(lo, batch, post, True)
    _close_vec("mu_star ref", ms_ref, ms_spec)
    _close_vec("mu_star compiled", ms_got, ms_spec)
    _close_mat("C_sum ref", C_ref[None], C_spec[None])
    _close_mat("C_sum compiled", C_got[None], C_spec[None])
    ms2, none = action_statistics_compiled(lo, batch, post, False)
    np.testing.assert_array_equal(ms2, ms_got)
    assert none is None and action_stats.action_statistics(lo, batch, post, False)[1] is None
    # residual covariance, NumPy vs compiled
    rng = np.random.default_rng(0)
    pred = ms_got + rng.normal(0, 1.0, ms_got.shape) * [1, 1, 0.01]
    R_ref = action_stats.residual_cov(ms_got, pred, lo.cov_scale, lo.cov_sd)
    R_got = residual_cov_compiled(ms_got, pred, lo.cov_scale, lo.cov_sd)
    _close_mat("residual cov", R_got[None], R_ref[None])
    r = ms_got - pred
    np.testing.assert_allclose(R_ref, _whitened_sum(lo, r[:, :, None] * r[:, None, :]), rtol=1e-12)


def test_residual_cov_sums_in_frame_order():
    """With unit scales the compiled sum is the plain sequential sum (what the table-indexed kernel did)."""
    rng = np.random.default_rng(1)
    ms = rng.normal(0, 10, (1000, 3))
    pred = rng.normal(0, 10, (1000, 3))
    got = residual_cov_compiled(ms, pred, np.ones(1000))
    acc = np.zeros((3, 3))
    for r in ms - pred:
        acc += np.outer(r, r)
    np.testing.assert_array_equal(got, acc)


def _sensor_pair(lo, batch, post, method, n_samples=1, degree=3, seed=7):
    r1, r2 = np.random.default_rng(seed), np.random.default_rng(seed)
    got = sensor_update_compiled(lo, batch, post, r1, method, n_samples, degree)
    ref = sensor_stats.update_sensor_curve(lo, batch, post, r2, method, n_samples, degree)
    assert r1.bit_generator.state == r2.bit_generator.state  # same draws from the generator
    return got, ref


def _assert_sensor_close(got, ref, tol=TOL):
    np.testing.assert_allclose(got[0], ref[0], rtol=tol, atol=0)
    np.testing.assert_allclose(got[1:3], ref[1:3], rtol=tol, atol=0)
    np.testing.assert_allclose(got[3], ref[3], rtol=tol, atol=0)


@pytest.mark.parametrize("name", CASES)
@pytest.mark.parametrize("method", ["cubature", "sample"])
def test_sensor_update_matches_reference(name, method):
    lo, batch, _ = case(name)
    post = smooth_compiled(lo, batch, GATE)
    batch = batch.with_used(batch.used & ~(post.mahal2 > GATE))  # the loop prunes gated sightings
    post = smooth_compiled(lo, batch, None)
    got, ref = _sensor_pair(lo, batch, post, method)
    _assert_sensor_close(got, ref)


def test_sensor_update_several_samples_and_degrees():
    for name in ("multi", "inverse"):
        lo, batch, _ = case(name)
        post = smooth_compiled(lo, batch, None)
        _assert_sensor_close(*_sensor_pair(lo, batch, post, "sample", n_samples=4, seed=3))
        for degree in (1, 2, 5):
            for method in ("cubature", "sample"):
                _assert_sensor_close(*_sensor_pair(lo, batch, post, method, degree=degree, seed=1), tol=1e-8)


def test_sensor_update_recovers_the_true_curve_with_effects():
    """With per-sighting scales/offsets/variance factors, the fit recovers the simulated curve
    (in its basis) and sigmas, which a fit ignoring the effects does not."""
    for name in ("effects", "inverse"):
        lo, batch, pose = case(name)
        post = smooth_compiled(lo, batch, GATE)
        batch = batch.with_used(batch.used & ~(post.mahal2 > GATE))
        post = smooth_compiled(lo, batch, None)
        coef, s_s, s_b, (d0, d1) = sensor_update_compiled(lo, batch, post, None, "cubature")
        d = np.linspace(d0, d1, 50)
        f_true = curve(lo.basis, pinhole_coef(lo.basis), d)[0]
        err = np.abs(curve(lo.basis, coef, d)[0] - f_true).max()
        assert err < 2.0, (name, err)
        assert 0.5 < s_s < 1.6 and 0.02 < s_b < 0.05, (name, s_s, s_b)
        plain = replace(lo, size_scale=np.ones_like(lo.size_scale), size_offset=np.zeros_like(lo.size_offset),
                        bearing_offset=np.zeros_like(lo.bearing_offset))  # fmt: skip
        _, s_s2, s_b2, _ = sensor_update_compiled(plain, batch, post, None, "cubature")
        assert s_s2 > 1.5 * s_s and s_b2 > 1.2 * s_b, (name, s_s, s_s2, s_b, s_b2)


def test_sensor_update_errors_like_reference():
    lo, batch, _ = case("multi")
    post = smooth_compiled(lo, batch, None)
    q = int(np.flatnonzero(batch.used)[5])
    cov = post.cov_gamma.copy()
    cov[batch.sight_pose[q]] = -np.eye(3)
    bad = replace(post, cov_gamma=cov)
    for fn in (sensor_update_compiled, sensor_stats.update_sensor_curve):
        rng = np.random.default_rng(0)
        before = rng.bit_generator.state
        with pytest.raises(FloatingPointError):
            fn(lo, batch, bad, rng, "sample")
        assert rng.bit_generator.state == before
    few = batch.with_used(batch.used & (np.cumsum(batch.used) <= 3))
    for fn in (sensor_update_compiled, sensor_stats.update_sensor_curve):
        with pytest.raises(ValueError, match="need at least"):
            fn(lo, few, post, np.random.default_rng(0), "sample")


@pytest.mark.parametrize("gate", [None, GATE])
def test_bearing_var_factor_in_both_e_steps_and_sensor_updates(gate):
    """A per-sighting bearing variance factor (``false_sightings`` inflates it by 1/responsibility):
    compiled == spec == reference, it changes the answer, and the sensor M-steps agree."""
    lo, batch, _ = case("effects")
    rng = np.random.default_rng(5)
    lo = replace(lo, bearing_var_factor=np.where(rng.random(batch.n_sightings) < 0.1, 1e4, rng.uniform(0.5, 3.0, batch.n_sightings)))
    got = smooth_compiled(lo, batch, gate)
    spec = _spec_smooth(lo, batch, gate)
    _compare_posteriors(got, spec)
    _compare_posteriors(smooth(lo, batch, gate), spec)
    plain = smooth_compiled(replace(lo, bearing_var_factor=None), batch, gate)
    assert np.abs(plain.mu_gamma - got.mu_gamma).max() > 1e-3 and abs(plain.loglik - got.loglik) > 1e-3
    for method in ("cubature", "sample"):
        _assert_sensor_close(*_sensor_pair(lo, batch.with_used(batch.used & ~(got.mahal2 > GATE)), got, method))
