"""Compiled (numba) action statistics: the fused ``_action_stats_kernel`` (``action_statistics_compiled``)
and ``_table_residual_kernel`` (``residual_cov_compiled``, ``table_residual_cov_compiled``). Twins of
``action_stats.action_statistics`` / ``action_stats.residual_cov``; docs/em-math.md is the specification.
Units: mm, mm, rad per frame.

The mu*_i, C*_i of ``action_stats.action_statistics``, rearranged so that each frame needs ONE 3x3
inverse and C*_i is never formed. With Sigma_i = cov_scale_i D_i Sigma_A D_i, B = (I + Y'P1)^-1,
Y_d = B Y', y_d = B (y' + Y' m1):
    I + Y_d Sigma_i = B (I + Y' (P1 + Sigma_i))  =>  with K = (I + Y' (P1 + Sigma_i))^-1:
    C*_i = (Sigma_i^-1 + Y_d)^-1 = Sigma_i K (I + Y' P1),
    mu*_i = mu_hat + Sigma_i K (y' + Y' (m1 - mu_hat)).
So D_i^-1 C*_i D_i^-1 / cov_scale_i = Sigma_A D_i K (I + Y'P1) D_i^-1, and the M-step's sum of them is Sigma_A times
sum_i D_i K_i (I + Y'_i P1_i) D_i^-1.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from learners.arrays.batch import Batch
from learners.arrays.lowered import Lowered
from learners.arrays.posterior import Posterior
from learners.inference.kernels.algebra import (
    _BAD_ACTION,
    _OK,
    _ZERO33,
    _add,
    _f64,
    _fin3,
    _fin33,
    _fpft,
    _inv,
    _inv_i_plus,
    _ld3,
    _ld33,
    _mm,
    _mv,
    _raise,
    _scratch,
    _st3,
)
from learners.inference.kernels.fasttrig import _cos_sin_all


@njit(cache=True)
def _rot_sandwich(c, s, A):
    """R A R^T for R = [[c, -s, 0], [s, c, 0], [0, 0, 1]] (A a row-major 9-tuple)."""
    b0 = c * A[0] - s * A[3]
    b1 = c * A[1] - s * A[4]
    b2 = c * A[2] - s * A[5]
    b3 = s * A[0] + c * A[3]
    b4 = s * A[1] + c * A[4]
    b5 = s * A[2] + c * A[5]
    return (
        c * b0 - s * b1, s * b0 + c * b1, b2,
        c * b3 - s * b4, s * b3 + c * b4, b5,
        c * A[6] - s * A[7], s * A[6] + c * A[7], A[8],
    )  # fmt: skip


@njit(cache=True, nogil=True, error_model="numpy")
def _action_stats_kernel(frame_start, disp, offset, cov_scale, cov_sd, sig_a, mu_alpha, cov_alpha, mu_gamma, info_delta,
                         vec_delta, need_cov, mu_star, cov_out, cos_th, sin_th):  # fmt: skip
    """Fills mu_star (N, 3) and (if need_cov) cov_out (3, 3) = sum_i D_i^-1 C*_i D_i^-1 / cov_scale_i.
    Returns (status, log index, frame index within the log).

    Evaluated in the world frame: with R = R3(theta_p) = L2^T and J = L2^T L1 = -(I with
    J[0,2] = -dy, J[1,2] = dx) (dx, dy = smoothed end minus offset minus start position),
    K = L2 Kw L2^T, Kw = (I + Y_delta (J P_alpha J^T + cov_scale R D Sigma D R^T))^-1, and
    mu*_i = mu_hat + cov_scale D Sigma D L2 Kw (y_delta + Y_delta (J (mu_alpha - g0) - g0 - offset - R mu_hat)),
    D^-1 C*_i D^-1 / cov_scale = Sigma D L2 Kw (I + Y_delta J P_alpha J^T) L2^T D^-1.
    """
    Sig = _ld33(sig_a.reshape(1, 3, 3), 0)
    _, det = _inv(Sig)
    if not (math.isfinite(det) and det != 0.0):  # the reference inverts Sigma: singular is an error
        return _BAD_ACTION, -1, -1
    Asum = _ZERO33
    n_logs = frame_start.shape[0] - 1
    for k in range(n_logs):
        f0 = frame_start[k]
        f1 = frame_start[k + 1]
        ps = f0 + k
        for j in range(f1 - f0):
            i = f0 + j
            p = ps + j
            g0 = _ld3(mu_gamma, p)
            c = cos_th[p]  # of the smoothed start heading g0[2]
            s = sin_th[p]
            o = _ld3(offset, i)
            dx = mu_gamma[p + 1, 0] - g0[0] - o[0]
            dy = mu_gamma[p + 1, 1] - g0[1] - o[1]
            mh = _ld3(disp, i)
            w_i = cov_scale[i]
            d0, d1, d2 = cov_sd[i, 0], cov_sd[i, 1], cov_sd[i, 2]
            SigD = (d0 * d0 * Sig[0], d0 * d1 * Sig[1], d0 * d2 * Sig[2], d1 * d0 * Sig[3], d1 * d1 * Sig[4],
                    d1 * d2 * Sig[5], d2 * d0 * Sig[6], d2 * d1 * Sig[7], d2 * d2 * Sig[8])  # D Sigma D
            P1w = _fpft(_ld33(cov_alpha, p), -dy, dx)  # J P_alpha J^T
            Q = _rot_sandwich(c, s, SigD)
            Mw = _add(P1w, (w_i * Q[0], w_i * Q[1], w_i * Q[2], w_i * Q[3], w_i * Q[4], w_i * Q[5], w_i * Q[6],
                            w_i * Q[7], w_i * Q[8]))  # fmt: skip
            Y = _ld33(info_delta, i)
            Kw = _inv_i_plus(_mm(Y, Mw))
            # w = J (mu_alpha - g0) - g0 - offset - R mu_hat
            e0 = mu_alpha[p, 0] - g0[0]
            e1 = mu_alpha[p, 1] - g0[1]
            e2 = mu_alpha[p, 2] - g0[2]
            w = (-e0 + dy * e2 - g0[0] - (c * mh[0] - s * mh[1]) - o[0],
                 -e1 - dx * e2 - g0[1] - (s * mh[0] + c * mh[1]) - o[1],
                 -e2 - g0[2] - mh[2] - o[2])  # fmt: skip
            Yw = _mv(Y, w)
            v = _mv(Kw, (vec_delta[i, 0] + Yw[0], vec_delta[i, 1] + Yw[1], vec_delta[i, 2] + Yw[2]))
            v = (c * v[0] + s * v[1], -s * v[0] + c * v[1], v[2])  # L2 v
            q = _mv(SigD, v)
            ms = (mh[0] + w_i * q[0], mh[1] + w_i * q[1], mh[2] + w_i * q[2])
            _st3(mu_star, i, ms)
            if not (_fin3(ms) and _fin33(Kw)):
                return _BAD_ACTION, k, j
            if need_cov:
                YP = _mm(Y, P1w)
                Aw = _mm(Kw, (1.0 + YP[0], YP[1], YP[2], YP[3], 1.0 + YP[4], YP[5], YP[6], YP[7], 1.0 + YP[8]))
                M = _rot_sandwich(c, -s, Aw)  # L2 Aw L2^T, then D M D^-1
                Asum = _add(Asum, (M[0], d0 * M[1] / d1, d0 * M[2] / d2, d1 * M[3] / d0, M[4], d1 * M[5] / d2,
                                   d2 * M[6] / d0, d2 * M[7] / d1, M[8]))  # fmt: skip
    if need_cov:
        C = _mm(Sig, Asum)
        for t in range(9):
            cov_out[t // 3, t % 3] = C[t]
        if not _fin33(C):
            return _BAD_ACTION, -1, -1
    return _OK, -1, -1


def action_statistics_compiled(lo: Lowered, batch: Batch, post: Posterior, need_cov: bool):
    """Compiled twin of ``action_stats.action_statistics``: (mu_star (N, 3), C_sum (3, 3) or None),
    without forming the (N, 3, 3) C*_i. ``mu_star`` is a per-thread work array, overwritten by the next
    call: use it before then (fresh 0.6 MB per EM iteration cost more in page faults than the kernel)."""
    n = batch.n_frames
    mu_star = _scratch("mu_star", (n, 3))
    cov = np.zeros((3, 3))
    mu_gamma = _f64(post.mu_gamma)
    cos_th = _scratch("cos_th", (mu_gamma.shape[0],))
    sin_th = _scratch("sin_th", (mu_gamma.shape[0],))
    _cos_sin_all(mu_gamma[:, 2], cos_th, sin_th)
    status, k, j = _action_stats_kernel(
        np.ascontiguousarray(batch.frame_start, dtype=np.int64), _f64(lo.disp, (n, 3)), _f64(lo.offset, (n, 3)),
        _f64(lo.cov_scale, (n,)), _f64(lo.cov_sd, (n, 3)), _f64(lo.cov, (3, 3)), _f64(post.mu_alpha), _f64(post.cov_alpha), mu_gamma,
        _f64(post.info_delta), _f64(post.vec_delta), bool(need_cov), mu_star, cov, cos_th, sin_th,
    )  # fmt: skip
    _raise(status, k, j, batch)
    return mu_star, (cov if need_cov else None)


def residual_cov_compiled(mu_star: np.ndarray, pred: np.ndarray, cov_scale: np.ndarray,
                          cov_sd: np.ndarray | None = None) -> np.ndarray:
    """Compiled twin of ``action_stats.residual_cov``: sum_i D_i^-1 r_i r_i^T D_i^-1 / cov_scale_i (3, 3), r_i = mu*_i -
    pred_i, D_i = diag(cov_sd[i]) (None: ones), summed in frame order like the table-indexed kernel's pass 2
    (bit-identical with unit scales)."""
    n = len(mu_star)
    return table_residual_cov_compiled(np.arange(n), mu_star, _f64(pred, (n, 3)), cov_scale,
                                       cov_sd)  # row i predicts frame i


# ----------------------------------------------------------------------------------------------
# the one-hot (table) case of the regression, fused: the paper's per-command means and the residual
# scatter without materializing the (N, 3) predictions (same sums, in frame order, as the NumPy path)
# ----------------------------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def _table_means_kernel(commands, mu_star, old, out):
    """out[a] = mean of mu_star over the frames of command a (old[a] where a is never executed)."""
    n_act = old.shape[0]
    sums = np.zeros((n_act, 3))
    counts = np.zeros(n_act)
    for i in range(commands.shape[0]):
        a = commands[i]
        sums[a, 0] += mu_star[i, 0]
        sums[a, 1] += mu_star[i, 1]
        sums[a, 2] += mu_star[i, 2]
        counts[a] += 1.0
    for a in range(n_act):
        for k in range(3):
            out[a, k] = sums[a, k] / counts[a] if counts[a] > 0 else old[a, k]


def table_means_compiled(commands: np.ndarray, mu_star: np.ndarray, old: np.ndarray) -> np.ndarray:
    """Compiled twin of ``ActionModel.regress`` for a table (one-hot features): (A, 3) per-command means."""
    out = np.empty_like(old, dtype=np.float64)
    _table_means_kernel(np.ascontiguousarray(commands, dtype=np.int64), _f64(mu_star), _f64(old), out)
    return out


@njit(cache=True, nogil=True)
def _table_residual_kernel(commands, mu_star, weights, cov_scale, cov_sd):
    """sum_i r_i r_i^T / cov_scale_i, r_i = D_i^-1 (mu_star_i - weights[commands_i]), in frame order (upper
    triangle)."""
    r00 = r01 = r02 = r11 = r12 = r22 = 0.0
    for i in range(mu_star.shape[0]):
        a = commands[i]
        iw = 1.0 / cov_scale[i]
        r0 = (mu_star[i, 0] - weights[a, 0]) / cov_sd[i, 0]
        r1 = (mu_star[i, 1] - weights[a, 1]) / cov_sd[i, 1]
        r2 = (mu_star[i, 2] - weights[a, 2]) / cov_sd[i, 2]
        r00 += r0 * r0 * iw
        r01 += r0 * r1 * iw
        r02 += r0 * r2 * iw
        r11 += r1 * r1 * iw
        r12 += r1 * r2 * iw
        r22 += r2 * r2 * iw
    return r00, r01, r02, r11, r12, r22


def table_residual_cov_compiled(commands: np.ndarray, mu_star: np.ndarray, weights: np.ndarray,
                                cov_scale: np.ndarray, cov_sd: np.ndarray | None = None) -> np.ndarray:
    """``residual_cov_compiled(mu_star, weights[commands], cov_scale, cov_sd)`` without forming the predictions."""
    n = len(mu_star)
    sd = np.ones((n, 3)) if cov_sd is None else _f64(cov_sd, (n, 3))
    r00, r01, r02, r11, r12, r22 = _table_residual_kernel(np.ascontiguousarray(commands, dtype=np.int64),
                                                          _f64(mu_star, (n, 3)), _f64(weights), _f64(cov_scale, (n,)),
                                                          sd)  # fmt: skip
    return np.array([[r00, r01, r02], [r01, r11, r12], [r02, r12, r22]])
