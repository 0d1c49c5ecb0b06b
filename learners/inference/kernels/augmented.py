"""Compiled (numba) twin of the augmented E-step (``learners.inference.augmented``: the pose plus K extra
scalar states, forward EKF + Rauch-Tung-Striebel backward pass); docs/em-math.md, "Extra states", is the
specification. Used only when an effect adds states (``Lowered.extra``): the base model keeps the
hand-unrolled 3x3 kernel of ``estep``.

Dense n x n algebra (n = 3 + K) on preallocated work arrays, with the structure of the motion used
where it is free: F = I except F[0,2], F[1,2] on the pose and diag(phi) on the extra states, so
F P F^T is O(n^2); the sighting updates are rank-2 (Joseph form); the RTS gain solves P- X = F P by
Cholesky (O(n^3) per frame). Equal to the reference to rounding (tests: 1e-9).

The O(n^3) loops of the backward pass (the Cholesky factor's solve, (C - P-) X and G W) run row by row over
contiguous columns, each entry's sum in the same order as an inner product would take it, so the compiler can run
the columns side by side (2026-12-01, MRCLAM robot 1's whole log with 8 bearing states, n = 11, best of 15 smooths:
54 -> 38 ms; `aibo diagnose` of it with `landmark_bearing_bias` among the candidates, idle, one after the other:
141 -> 103 s wall, 226 -> 160 s user CPU). The rebuilt module moves the results in the last digits (the forward
pass's log-likelihood by 3e-12 nats: the compiler inlines and schedules the module anew), not beyond the 1e-9 of
the tests. The factor itself, reordered the same way, measured no faster (38.4 / 37.1 against 39.0 / 37.0 ms).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from learners.arrays.batch import Batch
from learners.arrays.lowered import Lowered
from learners.arrays.posterior import ExtraMoments, Posterior
from learners.inference.augmented import posterior
from learners.inference.kernels.algebra import (
    _BAD_BACKWARD,
    _BAD_FORWARD,
    _LOG_2PI,
    _OK,
    _curve,
    _f64,
    _ld33,
    _raise,
    _scratch,
    _sym,
    _wrap,
)
from learners.inference.kernels.arguments import kernel_inputs
from learners.inference.kernels.structured import _dscale_sym, _rot_sym


@njit(cache=True, error_model="numpy")
def _f_rows(P, fa, fb, phi, out):
    """out = F P for F = I + fa e0 e2^T + fb e1 e2^T on the pose and diag(phi) on the extra states."""
    n = P.shape[0]
    for c in range(n):
        out[0, c] = P[0, c] + fa * P[2, c]
        out[1, c] = P[1, c] + fb * P[2, c]
        out[2, c] = P[2, c]
        for e in range(n - 3):
            out[3 + e, c] = phi[e] * P[3 + e, c]


@njit(cache=True, error_model="numpy")
def _predict_cov(P, fa, fb, phi, q, qpose, work):
    """P <- F P F^T + Q in place (Q: the 3x3 pose block ``qpose`` and diag(q)), symmetrized."""
    n = P.shape[0]
    _f_rows(P, fa, fb, phi, work)
    for r in range(n):
        P[r, 0] = work[r, 0] + fa * work[r, 2]
        P[r, 1] = work[r, 1] + fb * work[r, 2]
        P[r, 2] = work[r, 2]
        for e in range(n - 3):
            P[r, 3 + e] = phi[e] * work[r, 3 + e]
    for r in range(3):
        for c in range(3):
            P[r, c] += qpose[r, c]
    for e in range(n - 3):
        P[3 + e, 3 + e] += q[e]
    _symmetrize(P)


@njit(cache=True, error_model="numpy")
def _symmetrize(P):
    n = P.shape[0]
    for r in range(n):
        for c in range(r + 1, n):
            v = 0.5 * (P[r, c] + P[c, r])
            P[r, c] = v
            P[c, r] = v


@njit(cache=True, error_model="numpy")
def _cholesky(A, L):
    """Lower Cholesky factor of A into L; False if A is not positive definite."""
    n = A.shape[0]
    for r in range(n):
        for c in range(r + 1):
            s = A[r, c]
            for k in range(c):
                s -= L[r, k] * L[c, k]
            if r == c:
                if not s > 0.0:
                    return False
                L[r, r] = math.sqrt(s)
            else:
                L[r, c] = s / L[c, c]
        for c in range(r + 1, n):
            L[r, c] = 0.0
    return True


@njit(cache=True, error_model="numpy")
def _chol_solve(L, B):
    """B <- A^-1 B in place, A = L L^T (every column of B): L y = B forward, then L^T x = y backward, row by row over
    every column at once (each entry's sum in the same order as column by column)."""
    n = L.shape[0]
    for r in range(n):
        for k in range(r):
            _sub_row(B, r, k, L[r, k])
        _div_row(B, r, L[r, r])
    for r in range(n - 1, -1, -1):
        for k in range(r + 1, n):
            _sub_row(B, r, k, L[k, r])
        _div_row(B, r, L[r, r])


@njit(cache=True, error_model="numpy")
def _sub_row(B, r, k, f):
    """B[r] -= f B[k]."""
    for col in range(B.shape[1]):
        B[r, col] -= f * B[k, col]


@njit(cache=True, error_model="numpy")
def _div_row(B, r, d):
    """B[r] /= d."""
    for col in range(B.shape[1]):
        B[r, col] /= d


@njit(cache=True, error_model="numpy")
def _finite(mu, P):
    ok = 0.0
    for r in range(P.shape[0]):
        ok += mu[r] - mu[r]
        for c in range(P.shape[1]):
            ok += P[r, c] - P[r, c]
    return ok == 0.0


@njit(cache=True, error_model="numpy")
def _update(mu, P, qq, sight_xy, sight_value, basis, coef, sc, so, bo, sl, bl, var_h, vb, ph0, ph1, out):
    """The innovation of sighting qq at the belief (mu, P), not applied: ``out`` = [v0, v1 (wrapped),
    S00, S01, S11, then H's non-constant entries e0, e1, t0, t1 and the size's derivative in b], and
    ph0, ph1 = P H^T. ``sl``: its size state (-1: none); ``bl``: its bearing state (H[1, 3 + bl] = 1; -1: none)."""
    dx = sight_xy[qq, 0] - mu[0]
    dy = sight_xy[qq, 1] - mu[1]
    d2 = dx * dx + dy * dy
    d = math.sqrt(d2)
    fd, fp = _curve(basis, coef, d)
    mfac = 1.0 + mu[3 + sl] if sl >= 0 else 1.0
    cv = sc * fd  # size_scale f(d): the derivative of the size in b
    e0 = -sc * fp * mfac * dx / d
    e1 = -sc * fp * mfac * dy / d
    t0 = dy / d2
    t1 = -dx / d2
    v0 = sight_value[qq, 0] - (cv * mfac + so)
    v1 = _wrap(sight_value[qq, 1] - (math.atan2(dy, dx) - mu[2] + bo + (mu[3 + bl] if bl >= 0 else 0.0)))
    n = P.shape[0]
    for r in range(n):
        a = P[r, 0] * e0 + P[r, 1] * e1
        if sl >= 0:
            a += P[r, 3 + sl] * cv
        ph0[r] = a
        a = P[r, 0] * t0 + P[r, 1] * t1 - P[r, 2]
        if bl >= 0:
            a += P[r, 3 + bl]
        ph1[r] = a
    h0ph1 = e0 * ph1[0] + e1 * ph1[1]
    s00 = e0 * ph0[0] + e1 * ph0[1] + var_h
    if sl >= 0:
        s00 += cv * ph0[3 + sl]
        h0ph1 += cv * ph1[3 + sl]
    s11 = t0 * ph1[0] + t1 * ph1[1] - ph1[2] + vb
    h1ph0 = t0 * ph0[0] + t1 * ph0[1] - ph0[2]
    if bl >= 0:
        s11 += ph1[3 + bl]
        h1ph0 += ph0[3 + bl]
    s01 = 0.5 * (h0ph1 + h1ph0)
    out[0], out[1], out[2], out[3], out[4] = v0, v1, s00, s01, s11
    out[5], out[6], out[7], out[8], out[9] = e0, e1, t0, t1, cv


@njit(cache=True, error_model="numpy")
def _apply(mu, P, sl, bl, var_h, vb, ph0, ph1, X, xh0, xh1, k0, k1, o):
    """The EKF update with the innovation prepared by ``_update`` (``o``), Joseph form:
    K = P H^T S^-1, mu += K v, P = (I - K H) P (I - K H)^T + K R K^T (symmetrized)."""
    v0, v1, s00, s01, s11, e0, e1, t0, t1, cv = o[0], o[1], o[2], o[3], o[4], o[5], o[6], o[7], o[8], o[9]
    rdet = 1.0 / (s00 * s11 - s01 * s01)
    i00, i11, i01 = s11 * rdet, s00 * rdet, -s01 * rdet
    n = P.shape[0]
    for r in range(n):
        k0[r] = ph0[r] * i00 + ph1[r] * i01
        k1[r] = ph0[r] * i01 + ph1[r] * i11
        mu[r] += k0[r] * v0 + k1[r] * v1
    for r in range(n):  # X = (I - K H) P = P - k0 ph0^T - k1 ph1^T
        for c in range(n):
            X[r, c] = P[r, c] - k0[r] * ph0[c] - k1[r] * ph1[c]
    for r in range(n):  # X H^T
        a = X[r, 0] * e0 + X[r, 1] * e1
        if sl >= 0:
            a += X[r, 3 + sl] * cv
        xh0[r] = a
        a = X[r, 0] * t0 + X[r, 1] * t1 - X[r, 2]
        if bl >= 0:
            a += X[r, 3 + bl]
        xh1[r] = a
    for r in range(n):  # X (I - K H)^T + K R K^T
        g0 = var_h * k0[r] - xh0[r]
        g1 = vb * k1[r] - xh1[r]
        for c in range(n):
            P[r, c] = X[r, c] + g0 * k0[c] + g1 * k1[c]
    _symmetrize(P)


class ExtraInputs(NamedTuple):
    """The K extra scalar states (``Lowered.extra``): N frames, S sightings, L logs."""

    slot: np.ndarray  # (S,) int64: the extra state a sighting's size is multiplied by (1 + b), -1 for none
    bearing_slot: np.ndarray  # (S,) int64: the extra state added to a sighting's bearing (rad), -1 for none
    phi: np.ndarray  # (N, K): each frame's transition factor b' = phi b + noise
    q: np.ndarray  # (N, K): its noise variance
    init_var: np.ndarray  # (L, K): each log's initial variance (mean 0)


class AugmentedOutputs(NamedTuple):
    """The augmented kernel's output and work arrays; n = 3 + K, P poses, N frames, S sightings."""

    mf: np.ndarray  # (P, n): forward filtered means (mm, mm, rad, then the extra states)
    Pf: np.ndarray  # (P, n, n): their covariances
    g_pred: np.ndarray  # (N, n): each frame's predicted mean (kept for the backward pass)
    P_pred: np.ndarray  # (N, n, n): its covariance
    fab: np.ndarray  # (N, 2): each frame's F[0,2], F[1,2]
    sm: np.ndarray  # (P, n): smoothed means (unset with forward_only)
    sc: np.ndarray  # (P, n, n): their covariances
    x_cross: np.ndarray  # (N, K): the extra states' lag-one covariances
    mahal2: np.ndarray  # (S,): squared Mahalanobis distance of each used sighting's innovation (NaN otherwise)
    innov: np.ndarray  # (S, 5) per applied sighting (NaN otherwise), or (0, 5): not stored


@njit(cache=True, error_model="numpy")
def _augmented_forward_log(k, f0, ps, nfr, fr, si, ex, sig, out, loglik):
    """Forward EKF on x = (pose, K extra states) of log k (frames f0 .. f0+nfr-1, poses ps .. ps+nfr).
    Returns (status, frame index within the log, loglik + this log's log-likelihood)."""
    disp, offset, cov_scale, cov_sd, phi, q = fr.disp, fr.offset, fr.cov_scale, fr.cov_sd, ex.phi, ex.q
    mf, Pf, g_pred, P_pred, fab, mahal2, innov = out.mf, out.Pf, out.g_pred, out.P_pred, out.fab, out.mahal2, out.innov
    n = mf.shape[1]
    K = n - 3
    store = innov.shape[0] == mahal2.shape[0]
    P = np.empty((n, n))
    W = np.empty((n, n))
    X = np.empty((n, n))
    mu = np.empty(n)
    ph0, ph1, xh0, xh1, k0, k1 = np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    o = np.empty(10)
    qpose = np.empty((3, 3))
    for r in range(n):
        mu[r] = fr.init_mean[k, r] if r < 3 else 0.0
        for c in range(n):
            P[r, c] = fr.init_cov[k, r, c] if (r < 3 and c < 3) else 0.0
    for e in range(K):
        P[3 + e, 3 + e] = ex.init_var[k, e]
    mf[ps, :] = mu
    Pf[ps, :, :] = P
    if not _finite(mu, P):
        return _BAD_FORWARD, 0, loglik
    for j in range(nfr):
        i = f0 + j
        c = math.cos(mu[2])
        s = math.sin(mu[2])
        ux, uy = disp[i, 0], disp[i, 1]
        fa = -s * ux - c * uy
        fb = c * ux - s * uy
        fab[i, 0], fab[i, 1] = fa, fb
        mu[0], mu[1], mu[2] = (mu[0] + (c * ux - s * uy) + offset[i, 0], mu[1] + (s * ux + c * uy) + offset[i, 1],
                               mu[2] + disp[i, 2] + offset[i, 2])  # fmt: skip
        for e in range(K):
            mu[3 + e] = phi[i, e] * mu[3 + e]
        Q = _rot_sym(c, s, _dscale_sym(cov_scale[i], cov_sd[i], sig))  # pose block: R Sigma_i R^T (as estep)
        for r in range(3):
            for cc in range(3):
                qpose[r, cc] = Q[3 * r + cc]
        _predict_cov(P, fa, fb, phi[i], q[i], qpose, W)
        g_pred[i, :] = mu
        P_pred[i, :, :] = P
        for qq in range(si.sight_start[i], si.sight_start[i + 1]):
            mahal2[qq] = np.nan
            if store:
                innov[qq, :] = np.nan
            if not si.used[qq]:
                continue
            var_h = si.var_s * si.size_var_factor[qq]
            vb = si.var_b * si.bearing_var_factor[qq]
            sl, bl = ex.slot[qq], ex.bearing_slot[qq]
            _update(mu, P, qq, si.xy, si.value, si.basis, si.coef, si.size_scale[qq], si.size_offset[qq],
                    si.bearing_offset[qq], sl, bl, var_h, vb, ph0, ph1, o)  # fmt: skip
            v0, v1, S00, S01, S11 = o[0], o[1], o[2], o[3], o[4]
            det_s = S00 * S11 - S01 * S01
            m2v = (v0 * (S11 * v0 - S01 * v1) + v1 * (S00 * v1 - S01 * v0)) / det_s
            mahal2[qq] = m2v
            if not (math.isfinite(m2v) and det_s > 0.0 and S00 > 0.0):
                return _BAD_FORWARD, j, loglik
            if si.use_gate and m2v > si.gate:
                continue
            loglik += -0.5 * (m2v + math.log(det_s) + 2.0 * _LOG_2PI)
            if store:
                innov[qq, 0], innov[qq, 1], innov[qq, 2], innov[qq, 3], innov[qq, 4] = v0, v1, S00, S01, S11
            _apply(mu, P, sl, bl, var_h, vb, ph0, ph1, X, xh0, xh1, k0, k1, o)
        mf[ps + j + 1, :] = mu
        Pf[ps + j + 1, :, :] = P
        if not _finite(mu, P):
            return _BAD_FORWARD, j, loglik
    return _OK, -1, loglik


@njit(cache=True, error_model="numpy")
def _rts_log(f0, ps, nfr, ex, out):
    """Rauch-Tung-Striebel backward pass of one log from its forward beliefs: the smoothed beliefs and the
    extra states' lag-one covariances. Returns (status, frame index within the log)."""
    mf, Pf, g_pred, P_pred, fab, sm, sc, x_cross = out.mf, out.Pf, out.g_pred, out.P_pred, out.fab, out.sm, out.sc, out.x_cross
    phi = ex.phi
    n = mf.shape[1]
    K = n - 3
    P = np.empty((n, n))
    W = np.empty((n, n))
    X = np.empty((n, n))
    L = np.empty((n, n))
    Pn = np.empty((n, n))
    mu = np.empty(n)
    mn = np.empty(n)
    last = ps + nfr
    mn[:] = mf[last]
    Pn[:, :] = Pf[last]
    sm[last, :] = mn
    sc[last, :, :] = Pn
    for j in range(nfr - 1, -1, -1):
        i = f0 + j
        p = ps + j
        _f_rows(Pf[p], fab[i, 0], fab[i, 1], phi[i], X)  # X = F P_p, then P-^-1 F P_p = G^T
        if not _cholesky(P_pred[i], L):
            return _BAD_BACKWARD, j
        _chol_solve(L, X)
        for r in range(n):  # m_p = mu_p + G (m_{p+1} - g_p)
            a = 0.0
            for c in range(n):
                a += X[c, r] * (mn[c] - g_pred[i, c])
            mu[r] = mf[p, r] + a
        for r in range(n):  # W = (C_{p+1} - P-) X (row by row: each entry's sum in the order of m)
            for c in range(n):
                W[r, c] = 0.0
            for m in range(n):
                d = Pn[r, m] - P_pred[i, r, m]
                for c in range(n):
                    W[r, c] += d * X[m, c]
        for e in range(K):  # the extra states' lag-one covariances: diagonal of G C_{p+1}
            a = 0.0
            for m in range(n):
                a += X[m, 3 + e] * Pn[m, 3 + e]
            x_cross[i, e] = a
        for r in range(n):  # C_p = P_p + G W (G W accumulated row by row in the order of m, then added)
            for c in range(n):
                P[r, c] = 0.0
            for m in range(n):
                g = X[m, r]
                for c in range(n):
                    P[r, c] += g * W[m, c]
            for c in range(n):
                P[r, c] += Pf[p, r, c]
        _symmetrize(P)
        if not _finite(mu, P):
            return _BAD_BACKWARD, j
        mn[:] = mu
        Pn[:, :] = P
        sm[p, :] = mn
        sc[p, :, :] = Pn
    return _OK, -1


@njit(cache=True, error_model="numpy")
def _augmented_kernel(fr, si, ex, out, forward_only):
    """Forward EKF + RTS on x = (pose, K extra states) for every log (fr: FrameInputs, si: SightingInputs,
    ex: ExtraInputs, out: AugmentedOutputs). Returns (status, log, frame, loglik)."""
    sig = _sym(_ld33(fr.sig_a.reshape(1, 3, 3), 0))
    loglik = 0.0
    for k in range(fr.frame_start.shape[0] - 1):
        f0 = fr.frame_start[k]
        nfr = fr.frame_start[k + 1] - f0
        ps = f0 + k
        status, j, loglik = _augmented_forward_log(k, f0, ps, nfr, fr, si, ex, sig, out, loglik)
        if status != _OK:
            return status, k, j, loglik
        if forward_only:
            continue
        status, j = _rts_log(f0, ps, nfr, ex, out)
        if status != _OK:
            return status, k, j, loglik
    return _OK, -1, -1, loglik


_NO_INNOV = np.empty((0, 5))


def _run(lo: Lowered, batch: Batch, gate: float | None, innov: np.ndarray, forward_only: bool):
    """The kernel on ``lo`` (which has extra states): (loglik, mahal2, ExtraMoments or None if forward_only)."""
    ex = lo.extra
    n, n_s, L, K = batch.n_frames, batch.n_sightings, batch.n_logs, ex.k
    n_poses = n + L
    dim = 3 + K
    slot = np.ascontiguousarray(ex.slot, dtype=np.int64)
    bearing_slot = np.ascontiguousarray(ex.bearing_slot, dtype=np.int64)
    for name, s in (("slot", slot), ("bearing_slot", bearing_slot)):
        if s.shape != (n_s,) or np.any(s >= K):
            raise ValueError(f"extra states: {name} must have one entry per sighting, each < {K}")
    extra = ExtraInputs(slot=slot, bearing_slot=bearing_slot, phi=_f64(ex.phi, (n, K)), q=_f64(ex.q, (n, K)),
                        init_var=_f64(ex.init_var, (L, K)))
    if forward_only:  # the beliefs are not returned: reused work arrays
        mf, Pf = _scratch("aug_mf", (n_poses, dim)), _scratch("aug_Pf", (n_poses, dim, dim))
        g_pred, P_pred = _scratch("aug_g", (n, dim)), _scratch("aug_Pp", (n, dim, dim))
    else:
        mf, Pf, g_pred, P_pred = np.empty((n_poses, dim)), np.empty((n_poses, dim, dim)), np.empty((n, dim)), np.empty((n, dim, dim))
    out = AugmentedOutputs(mf=mf, Pf=Pf, g_pred=g_pred, P_pred=P_pred, fab=_scratch("aug_fab", (n, 2)),
                           sm=np.empty((n_poses, dim)), sc=np.empty((n_poses, dim, dim)), x_cross=np.empty((n, K)),
                           mahal2=np.empty(n_s), innov=innov)
    status, k, j, loglik = _augmented_kernel(*kernel_inputs(lo, batch, gate), extra, out, forward_only)
    _raise(status, k, j, batch)
    if not math.isfinite(loglik):
        raise FloatingPointError("non-finite log-likelihood in the augmented E-step")
    moments = None if forward_only else ExtraMoments(mf, Pf, g_pred, P_pred, out.sm, out.sc, out.x_cross)
    return float(loglik), out.mahal2, moments


def smooth_augmented_compiled(lo: Lowered, batch: Batch, gate: float | None = None) -> Posterior:
    """Compiled twin of ``augmented.smooth_augmented`` (same contract)."""
    loglik, mahal2, extra = _run(lo, batch, gate, _NO_INNOV, False)
    return posterior(extra, loglik, mahal2)


def innovations_augmented_compiled(lo: Lowered, batch: Batch, out: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """The augmented forward EKF alone (no gate): (loglik, (S, 5) innovations) as ``estep.innovations_compiled``."""
    n_s = batch.n_sightings
    innov = out if out is not None and out.shape == (n_s, 5) else np.empty((n_s, 5))
    loglik, _, _ = _run(lo, batch, None, innov, True)
    return loglik, innov
