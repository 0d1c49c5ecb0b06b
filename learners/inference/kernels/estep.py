"""Compiled (numba) twin of the E-step: ``_smooth_kernel`` and its wrapper ``smooth_compiled``.

Same contract and equations as the plain-NumPy reference ``smoother.smooth``; docs/em-math.md is
the specification. Conventions match the reference:
- heading unwrapped in every mean; innovations wrapped to (-pi, pi];
- Joseph-form update, full one-step predictive S for the likelihood and mahal2;
- backward information filter from Y = 0, y = 0 at each log's last pose, linearized at the
  forward filtered means; combination into gamma in information form;
- covariances (and Y) symmetrized.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from learners.em.data import Batch
from learners.em.kernels.algebra import (
    _BAD_BACKWARD, _BAD_FORWARD, _BAD_GAMMA, _LOG_2PI, _OK, _ZERO3, _ZERO33, _add, _f64, _fin3, _fin33, _horner,
    _inv_i_plus, _ld3, _ld33, _mm, _mv, _raise, _scratch, _st3, _st33, _sym, _wrap,
)
from learners.em.kernels.fasttrig import _atan2, _cos_sin
from learners.em.params import Params
from learners.em.posterior import Posterior


# ----------------------------------------------------------------------------------------------
# E-step kernel
# ----------------------------------------------------------------------------------------------
#
# Speed notes (the equations are docs/em-math.md's; only rounding differs from the reference):
# - cos/sin of each forward filtered heading are computed once (``_cos_sin``) and kept in a
#   scratch array: the backward time update linearizes g at the same mu_alpha, so it rebuilds
#   F, Q and c = g - F mu from them without any trig;
# - bearings use the branch-free ``_atan2`` (<= 3 ulp);
# - F = I + (column 2) and Q = R Sigma_A R^T (Sigma_A symmetrized once) are applied through their
#   structure; symmetric results (P, Y, Q, Ytil, Sigma_gamma) are formed from their upper triangle,
#   which replaces the symmetrization (same matrix up to rounding);
# - H has the constant entries H[0,2] = 0, H[1,2] = -1, written out (x * 0.0 is not folded);
# - the backward observation information H^T R^-1 H, H^T R^-1 (v + H mu) at mu_alpha[i+1] is
#   computed by the forward pass right after that mean is known (off its serial chain) and parked
#   in info_delta[i] / vec_delta[i] (zero where no sighting is applied); the backward pass adds it
#   and overwrites the slot with Y_delta, y_delta;
# - combination: A - A M Y A = A M exactly (A M (I + Y A) = A), so Sigma_gamma = sym(A M);
# - the E-step's own functions may fuse a * b + c into one FMA (``_FMA``): fewer instructions on
#   the forward pass's serial chain, rounding-level differences only.

_FMA = {"contract"}


@njit(cache=True, fastmath=_FMA)
def _symm(a00, a01, a02, a11, a12, a22):
    """The symmetric 3x3 (row-major 9-tuple) with the given upper triangle."""
    return (a00, a01, a02, a01, a11, a12, a02, a12, a22)


@njit(cache=True, fastmath=_FMA)
def _rot_sym(c, s, A):
    """R A R^T for symmetric A, R = [[c, -s, 0], [s, c, 0], [0, 0, 1]] (upper triangle, mirrored)."""
    b0 = c * A[0] - s * A[3]
    b1 = c * A[1] - s * A[4]
    b3 = s * A[0] + c * A[3]
    b4 = s * A[1] + c * A[4]
    return _symm(c * b0 - s * b1, s * b0 + c * b1, c * A[2] - s * A[5], s * b3 + c * b4, s * A[2] + c * A[5], A[8])


@njit(cache=True, fastmath=_FMA)
def _fpft_sym(P, a, b):
    """F P F^T for symmetric P, F = I except F[0,2] = a, F[1,2] = b (upper triangle, mirrored)."""
    r02 = P[2] + a * P[8]
    r12 = P[5] + b * P[8]
    return _symm(P[0] + a * P[6] + a * r02, P[1] + a * P[7] + b * r02, r02,
                 P[4] + b * P[7] + b * r12, r12, P[8])  # fmt: skip


@njit(cache=True, fastmath=_FMA)
def _ftyf_sym(Y, a, b):
    """F^T Y F for symmetric Y, F = I except F[0,2] = a, F[1,2] = b (upper triangle, mirrored)."""
    r20 = Y[6] + a * Y[0] + b * Y[3]
    r21 = Y[7] + a * Y[1] + b * Y[4]
    r22 = Y[8] + a * Y[2] + b * Y[5]
    return _symm(Y[0], Y[1], r20, Y[4], r21, r22 + a * r20 + b * r21)


@njit(cache=True, error_model="numpy", fastmath=_FMA)
def _observe_h(mu, bx, by, coef):
    """(f(d), bearing (not wrapped), H) at pose mu, H as its 4 non-constant entries:
    row 0 = (e0, e1, 0), row 1 = (t0, t1, -1)."""
    dx = bx - mu[0]
    dy = by - mu[1]
    q = dx * dx + dy * dy
    d = math.sqrt(q)
    fd, fp = _horner(coef, d)
    fpd = fp / d
    rq = 1.0 / q
    return fd, _atan2(dy, dx) - mu[2], -fpd * dx, -fpd * dy, dy * rq, -dx * rq


@njit(cache=True, error_model="numpy", fastmath=_FMA)
def _combine_fast(ma, A, Y, y):
    """gamma from alpha N(ma, A) and beta information (Y, y): M = (I + Y A)^-1,
    mu = ma + A M (y - Y ma), cov = A - A M Y A = A M (symmetrized)."""
    AM = _mm(A, _inv_i_plus(_mm(Y, A)))
    Yma = _mv(Y, ma)
    w = _mv(AM, (y[0] - Yma[0], y[1] - Yma[1], y[2] - Yma[2]))
    return (ma[0] + w[0], ma[1] + w[1], ma[2] + w[2]), _sym(AM)



@njit(cache=True, error_model="numpy", fastmath=_FMA)
def _smooth_kernel(
    actions, obs, beacon_xy, used, frame_start, disp, sig_a, coef, var_h, var_a,
    init_mean, init_cov, use_gate, gate,
    mu_alpha, cov_alpha, mu_gamma, cov_gamma, info_delta, vec_delta, mahal2, cos_th, sin_th,
):  # fmt: skip
    """Returns (status, log index, frame index within the log, loglik).
    cos_th, sin_th (n_poses,): scratch, cos/sin of mu_alpha[:, 2] (every pose but each log's last)."""
    sig = _sym(_ld33(sig_a.reshape(1, 3, 3), 0))
    ivh = 1.0 / var_h
    iva = 1.0 / var_a
    loglik = 0.0
    n_logs = frame_start.shape[0] - 1
    for k in range(n_logs):
        f0 = frame_start[k]
        f1 = frame_start[k + 1]
        ps = f0 + k  # pose_start[k]
        n = f1 - f0

        # ---------------- forward EKF ----------------
        mu = _ld3(init_mean, k)
        P = _sym(_ld33(init_cov, k))
        _st3(mu_alpha, ps, mu)
        _st33(cov_alpha, ps, P)
        if not (_fin3(mu) and _fin33(P)):
            return _BAD_FORWARD, k, 0, loglik
        for j in range(n):
            i = f0 + j
            a = actions[i]
            ux = disp[a, 0]
            uy = disp[a, 1]
            c, s = _cos_sin(mu[2])
            cos_th[ps + j] = c  # for the backward pass
            sin_th[ps + j] = s
            fa = -s * ux - c * uy  # F[0,2]
            fb = c * ux - s * uy  # F[1,2]
            mu = (mu[0] + c * ux - s * uy, mu[1] + s * ux + c * uy, mu[2] + disp[a, 2])
            P = _add(_fpft_sym(P, fa, fb), _rot_sym(c, s, sig))  # P- = F P F^T + Q
            mahal2[i] = np.nan
            applied = False
            if used[i]:
                bx = beacon_xy[i, 0]
                by = beacon_xy[i, 1]
                fd, bear, e0, e1, t0, t1 = _observe_h(mu, bx, by, coef)
                v0 = obs[i, 0] - fd
                v1 = _wrap(obs[i, 1] - bear)
                # P- H^T columns ph0 = P- h0, ph1 = P- h1; S = H P- H^T + R_obs
                ph0 = (P[0] * e0 + P[1] * e1, P[3] * e0 + P[4] * e1, P[6] * e0 + P[7] * e1)
                ph1 = (P[0] * t0 + P[1] * t1 - P[2], P[3] * t0 + P[4] * t1 - P[5], P[6] * t0 + P[7] * t1 - P[8])
                s00 = e0 * ph0[0] + e1 * ph0[1] + var_h
                s11 = t0 * ph1[0] + t1 * ph1[1] - ph1[2] + var_a
                s01 = 0.5 * ((e0 * ph1[0] + e1 * ph1[1]) + (t0 * ph0[0] + t1 * ph0[1] - ph0[2]))
                det_s = s00 * s11 - s01 * s01
                rdet = 1.0 / det_s
                i00 = s11 * rdet
                i11 = s00 * rdet
                i01 = -s01 * rdet
                m2v = v0 * (i00 * v0 + i01 * v1) + v1 * (i01 * v0 + i11 * v1)
                mahal2[i] = m2v
                if not (math.isfinite(m2v) and det_s > 0.0 and s00 > 0.0):
                    return _BAD_FORWARD, k, j, loglik
                if not (use_gate and m2v > gate):
                    applied = True
                    loglik += -0.5 * (m2v + math.log(det_s) + 2.0 * _LOG_2PI)
                    # K = P- H^T S^-1 (columns k0, k1)
                    k0 = (ph0[0] * i00 + ph1[0] * i01, ph0[1] * i00 + ph1[1] * i01, ph0[2] * i00 + ph1[2] * i01)
                    k1 = (ph0[0] * i01 + ph1[0] * i11, ph0[1] * i01 + ph1[1] * i11, ph0[2] * i01 + ph1[2] * i11)
                    mu = (mu[0] + k0[0] * v0 + k1[0] * v1, mu[1] + k0[1] * v0 + k1[1] * v1,
                          mu[2] + k0[2] * v0 + k1[2] * v1)  # fmt: skip
                    # Joseph, (I - K H) P- (I - K H)^T + K R_obs K^T, as rank-2 updates:
                    # X = (I - K H) P- = P- - k0 ph0^T - k1 ph1^T (P- symmetric), then
                    # X (I - K H)^T = X - (X h0) k0^T - (X h1) k1^T
                    X = (P[0] - k0[0] * ph0[0] - k1[0] * ph1[0], P[1] - k0[0] * ph0[1] - k1[0] * ph1[1],
                         P[2] - k0[0] * ph0[2] - k1[0] * ph1[2], P[3] - k0[1] * ph0[0] - k1[1] * ph1[0],
                         P[4] - k0[1] * ph0[1] - k1[1] * ph1[1], P[5] - k0[1] * ph0[2] - k1[1] * ph1[2],
                         P[6] - k0[2] * ph0[0] - k1[2] * ph1[0], P[7] - k0[2] * ph0[1] - k1[2] * ph1[1],
                         P[8] - k0[2] * ph0[2] - k1[2] * ph1[2])  # fmt: skip
                    xh0 = (X[0] * e0 + X[1] * e1, X[3] * e0 + X[4] * e1, X[6] * e0 + X[7] * e1)
                    xh1 = (X[0] * t0 + X[1] * t1 - X[2], X[3] * t0 + X[4] * t1 - X[5], X[6] * t0 + X[7] * t1 - X[8])
                    # (r, c) entry of the symmetric result, r <= c
                    g0 = (var_h * k0[0] - xh0[0], var_h * k0[1] - xh0[1], var_h * k0[2] - xh0[2])
                    g1 = (var_a * k1[0] - xh1[0], var_a * k1[1] - xh1[1], var_a * k1[2] - xh1[2])
                    P = _symm(X[0] + g0[0] * k0[0] + g1[0] * k1[0], X[1] + g0[0] * k0[1] + g1[0] * k1[1],
                              X[2] + g0[0] * k0[2] + g1[0] * k1[2], X[4] + g0[1] * k0[1] + g1[1] * k1[1],
                              X[5] + g0[1] * k0[2] + g1[1] * k1[2], X[8] + g0[2] * k0[2] + g1[2] * k1[2])  # fmt: skip
            _st3(mu_alpha, i + k + 1, mu)
            _st33(cov_alpha, i + k + 1, P)
            if not (_fin3(mu) and _fin33(P)):
                return _BAD_FORWARD, k, j, loglik
            if applied:
                # backward observation information, h linearized at mu_alpha[i + 1] = mu:
                # H^T R_obs^-1 H and H^T R_obs^-1 (v + H mu), parked in the delta slots of frame i
                fd, bear, e0, e1, t0, t1 = _observe_h(mu, bx, by, coef)
                z0 = (obs[i, 0] - fd + (e0 * mu[0] + e1 * mu[1])) * ivh
                z1 = (_wrap(obs[i, 1] - bear) + (t0 * mu[0] + t1 * mu[1] - mu[2])) * iva
                _st33(info_delta, i, _symm(ivh * e0 * e0 + iva * t0 * t0, ivh * e0 * e1 + iva * t0 * t1, -iva * t0,
                                           ivh * e1 * e1 + iva * t1 * t1, -iva * t1, iva))  # fmt: skip
                _st3(vec_delta, i, (e0 * z0 + t0 * z1, e1 * z0 + t1 * z1, -z1))
            else:
                _st33(info_delta, i, _ZERO33)
                _st3(vec_delta, i, _ZERO3)

        # ---------------- backward information filter + combination ----------------
        Y = _ZERO33
        y = _ZERO3
        for j in range(n - 1, -1, -1):
            i = f0 + j
            p = ps + j
            # gamma at the end pose p + 1 (beta = (Y, y) there)
            mg, cg = _combine_fast(_ld3(mu_alpha, p + 1), _ld33(cov_alpha, p + 1), Y, y)
            _st3(mu_gamma, p + 1, mg)
            _st33(cov_gamma, p + 1, cg)
            if not (_fin3(mg) and _fin33(cg)):
                return _BAD_GAMMA, k, j, loglik
            # observation update at the end pose (the information parked by the forward pass)
            dY = _ld33(info_delta, i)
            dy = _ld3(vec_delta, i)
            Y = _symm(Y[0] + dY[0], Y[1] + dY[1], Y[2] + dY[2], Y[4] + dY[4], Y[5] + dY[5], Y[8] + dY[8])
            y = (y[0] + dy[0], y[1] + dy[1], y[2] + dy[2])
            _st3(vec_delta, i, y)
            _st33(info_delta, i, Y)
            # time update to pose p, g linearized at mu_alpha[p] (cos/sin kept by the forward pass):
            # c = g - F mu = (F[1,2] - F[0,2] th, -F[0,2] - F[1,2] th, ut)
            a = actions[i]
            ux = disp[a, 0]
            uy = disp[a, 1]
            c = cos_th[p]
            s = sin_th[p]
            fa = -s * ux - c * uy
            fb = c * ux - s * uy
            th = mu_alpha[p, 2]
            cv = (fb - fa * th, -fa - fb * th, disp[a, 2])
            B = _inv_i_plus(_mm(Y, _rot_sym(c, s, sig)))  # (I + Y_delta Q)^-1
            # Ytil = B Y_delta (symmetric: upper triangle), ytil = B y_delta
            Yt = _symm(B[0] * Y[0] + B[1] * Y[3] + B[2] * Y[6], B[0] * Y[1] + B[1] * Y[4] + B[2] * Y[7],
                       B[0] * Y[2] + B[1] * Y[5] + B[2] * Y[8], B[3] * Y[1] + B[4] * Y[4] + B[5] * Y[7],
                       B[3] * Y[2] + B[4] * Y[5] + B[5] * Y[8], B[6] * Y[2] + B[7] * Y[5] + B[8] * Y[8])  # fmt: skip
            yt = _mv(B, y)
            Ytc = _mv(Yt, cv)
            w0 = yt[0] - Ytc[0]
            w1 = yt[1] - Ytc[1]
            y = (w0, w1, yt[2] - Ytc[2] + fa * w0 + fb * w1)  # F^T (ytil - Ytil c)
            Y = _ftyf_sym(Yt, fa, fb)  # F^T Ytil F
            if not (_fin3(y) and _fin33(Y)):
                return _BAD_BACKWARD, k, j, loglik
        mg, cg = _combine_fast(_ld3(mu_alpha, ps), _ld33(cov_alpha, ps), Y, y)
        _st3(mu_gamma, ps, mg)
        _st33(cov_gamma, ps, cg)
        if not (_fin3(mg) and _fin33(cg)):
            return _BAD_GAMMA, k, 0, loglik
    return _OK, -1, -1, loglik


def smooth_compiled(params: Params, batch: Batch, gate: float | None = None, out: Posterior | None = None) -> Posterior:
    """Compiled E-step: forward EKF, backward information filter, combination (docs/em-math.md).

    Same contract as ``learners.em.smoother.smooth``. ``out``: a Posterior of the same batch whose
    arrays are overwritten and returned (the caller must no longer need it). ``gate``: a used sighting whose mahal2
    exceeds it is not applied (no update, no likelihood term, skipped by the backward pass);
    its mahal2 is still stored so the caller can prune it (``used & (mahal2 > gate)``).
    """
    n_logs = batch.n_logs
    if len(params.init) != n_logs:
        raise ValueError(f"params has {len(params.init)} initial states for {n_logs} logs")
    n = batch.n_frames
    n_poses = n + n_logs
    frame_start = np.ascontiguousarray(batch.frame_start, dtype=np.int64)
    actions = np.ascontiguousarray(batch.actions, dtype=np.int64)
    obs = _f64(batch.obs, (n, 2))
    beacon_xy = _f64(batch.beacon_xy, (n, 2))
    used = np.ascontiguousarray(batch.used, dtype=np.bool_)
    if used.shape != (n,) or actions.shape != (n,):
        raise ValueError("batch.actions / batch.used must have one entry per frame")
    disp = _f64(params.action.disp)
    if n and (actions.min() < 0 or actions.max() >= disp.shape[0]):
        raise ValueError("action index out of range")
    sig_a = _f64(params.action.cov, (3, 3))
    coef = _f64(params.sensor.coef).reshape(-1)
    if coef.size == 0:
        coef = np.zeros(1)
    var_h = float(params.sensor.sigma_height) ** 2
    var_a = float(params.sensor.sigma_angle) ** 2
    init_mean = np.ascontiguousarray(np.stack([np.asarray(s.mean, float).reshape(3) for s in params.init]))
    init_cov = np.ascontiguousarray(np.stack([np.asarray(s.cov, float).reshape(3, 3) for s in params.init]))
    use_gate = gate is not None
    gate_v = float(gate) if use_gate else np.inf

    if out is not None and out.mu_alpha.shape == (n_poses, 3) and out.mahal2.shape == (n,):
        # reuse the previous posterior's arrays: fresh 8 MB per call cost ~40% of the time (page faults)
        mu_alpha, cov_alpha, mu_gamma, cov_gamma = out.mu_alpha, out.cov_alpha, out.mu_gamma, out.cov_gamma
        info_delta, vec_delta, mahal2 = out.info_delta, out.vec_delta, out.mahal2
    else:
        mu_alpha = np.empty((n_poses, 3))
        cov_alpha = np.empty((n_poses, 3, 3))
        mu_gamma = np.empty((n_poses, 3))
        cov_gamma = np.empty((n_poses, 3, 3))
        info_delta = np.empty((n, 3, 3))
        vec_delta = np.empty((n, 3))
        mahal2 = np.empty(n)
    # cos/sin of the forward headings, reused by the backward pass (per-thread, reused across calls)
    cos_th = _scratch("estep_cos", (n_poses,))
    sin_th = _scratch("estep_sin", (n_poses,))
    status, k, j, loglik = _smooth_kernel(
        actions, obs, beacon_xy, used, frame_start, disp, sig_a, coef, var_h, var_a,
        init_mean, init_cov, use_gate, gate_v,
        mu_alpha, cov_alpha, mu_gamma, cov_gamma, info_delta, vec_delta, mahal2, cos_th, sin_th,
    )  # fmt: skip
    _raise(status, k, j, batch)
    if not math.isfinite(loglik):
        raise FloatingPointError("non-finite log-likelihood in the E-step")
    return Posterior(mu_alpha, cov_alpha, mu_gamma, cov_gamma, info_delta, vec_delta, float(loglik), mahal2)
