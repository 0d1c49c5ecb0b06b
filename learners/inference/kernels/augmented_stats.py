"""Compiled (numba) twin of the action statistics of an augmented E-step
(``learners.inference.augmented.displacement_statistics``; docs/em-math.md, "Extra states", is the
specification): per frame, the Gaussian over z = (x_p, d, b_{p+1}) of dimension D = 2 n (n = 3 + K)
built from the filtered belief at p, the bias transition, the smoother's information on the end state
and the frame's displacement prior, solved for the displacement's mean and covariance.

The reference does this with batched ``np.linalg.inv`` / ``solve`` on (N, D, D) arrays, in information form.
Here one frame at a time on preallocated work arrays, in MOMENT form (``_displacement_kernel``: the same
posterior by Woodbury's identity): the prior's moments are read off the filter without inverting its
covariance, and one n x n solve replaces the D x D Cholesky factorization and the four D-long solves of the
information form. Measured on MRCLAM robot 1's training half with 8 bias states (8,937 frames, minimum of 25
calls, alternated): 68.1 ms in information form (this kernel's previous version), 33.5 ms now; largest
difference 6e-11 mm in mu*. Equal to the reference to rounding (tests: 1e-9).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from learners.arrays.batch import Batch
from learners.arrays.lowered import Lowered
from learners.arrays.posterior import Posterior
from learners.inference.kernels.algebra import _f64
from learners.inference.kernels.augmented import _cholesky


@njit(cache=True, error_model="numpy")
def _spd_inverse(A, L, out):
    """out = A^-1 = L^-T L^-1 (A = L L^T, symmetric positive definite; L is overwritten by L^-1); False if A
    is not positive definite."""
    if not _cholesky(A, L):
        return False
    n = A.shape[0]
    for c in range(n):  # L <- L^-1 (lower triangular), column by column
        L[c, c] = 1.0 / L[c, c]
        for r in range(c + 1, n):
            s = 0.0
            for k in range(c, r):
                s -= L[r, k] * L[k, c]
            L[r, c] = s / L[r, r]
    for r in range(n):  # out = L^-T L^-1
        for c in range(r + 1):
            s = 0.0
            for k in range(r, n):
                s += L[k, r] * L[k, c]
            out[r, c] = s
            out[c, r] = s
    return True


@njit(cache=True, error_model="numpy")
def _symmetrized(A, out):
    n = A.shape[0]
    for r in range(n):
        for c in range(n):
            out[r, c] = 0.5 * (A[r, c] + A[c, r])


@njit(cache=True, error_model="numpy")
def _rel_disp_jac(s0x, s0y, s0t, s1x, s1y, s1t, L1, L2, m):
    """``aibo_core.geometry.rel_disp_jac`` at one point: L1, L2 (3x3) and m (3,) written in place."""
    c, s = math.cos(s0t), math.sin(s0t)
    dx, dy = s1x - s0x, s1y - s0y
    for r in range(3):
        for k in range(3):
            L2[r, k] = 0.0
    L2[0, 0], L2[0, 1], L2[1, 0], L2[1, 1], L2[2, 2] = c, s, -s, c, 1.0
    for r in range(3):
        for k in range(3):
            L1[r, k] = -L2[r, k]
    L1[0, 2] = -s * dx + c * dy
    L1[1, 2] = -c * dx - s * dy
    L1[2, 2] = -1.0
    d = (c * dx + s * dy, -s * dx + c * dy, s1t - s0t)
    s0 = (s0x, s0y, s0t)
    s1 = (s1x, s1y, s1t)
    for r in range(3):
        acc = d[r]
        for k in range(3):
            acc -= L1[r, k] * s0[k] + L2[r, k] * s1[k]
        m[r] = acc


@njit(cache=True, error_model="numpy")
def _lu_solve(A, B):
    """B <- A^-1 B in place by Gaussian elimination with partial pivoting (A, square and not symmetric, is
    overwritten); False if A is singular."""
    n, m = A.shape[0], B.shape[1]
    for col in range(n):
        piv, big = col, abs(A[col, col])
        for r in range(col + 1, n):
            if abs(A[r, col]) > big:
                piv, big = r, abs(A[r, col])
        if not big > 0.0:
            return False
        if piv != col:
            for k in range(n):
                A[col, k], A[piv, k] = A[piv, k], A[col, k]
            for k in range(m):
                B[col, k], B[piv, k] = B[piv, k], B[col, k]
        for r in range(col + 1, n):
            f = A[r, col] / A[col, col]
            if f != 0.0:
                for k in range(col + 1, n):
                    A[r, k] -= f * A[col, k]
                for k in range(m):
                    B[r, k] -= f * B[col, k]
    for r in range(n - 1, -1, -1):
        for k in range(m):
            s = B[r, k]
            for c in range(r + 1, n):
                s -= A[r, c] * B[c, k]
            B[r, k] = s / A[r, r]
    return True


@njit(cache=True, error_model="numpy")
def _displacement_kernel(frame_to_pose, offset, disp, cov, cov_scale, cov_sd, phi, q, f_mean, f_cov, p_mean, p_cov,
                         s_mean, s_cov, need_cov, mu_star, c_sum):
    """Fills mu_star (N, 3) and c_sum (3, 3); returns -1, or the first frame whose statistics are not finite
    or whose matrices are not positive definite (or I + Y S singular).

    The reference's posterior in its moment form (module docstring): the prior over z = (x_p, d, b_{p+1}) has
    moments m_z = (mu_p, disp_i, phi b_p) and P_z = [[P_p, 0, P_p[:, b] phi], [0, S_d, 0], [., 0, phi P_bb phi + q]]
    (S_d = cov_scale_i D_i Sigma_A D_i), the end state's information (Y, y) enters through u = M z + c, and by Woodbury
    J^-1 M^T = G (I + Y S)^-1 with G = P_z M^T, S = M G: mean m_z + G (I + Y S)^-1 (y - Y (M m_z + c)),
    covariance P_z - G (I + Y S)^-1 Y G^T. Only d's rows of G are needed: S_d [L2, 0]."""
    n_frames = disp.shape[0]
    n = f_mean.shape[1]
    K = n - 3
    Ln, tmp = np.empty((n, n)), np.empty((n, n))
    Js, Jp, Y, F = np.empty((n, n)), np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
    S, A = np.empty((n, n)), np.empty((n, n))
    y, u = np.empty(n), np.empty(n)
    L1, L2, m, A0 = np.empty((3, 3)), np.empty((3, 3)), np.empty(3), np.empty((3, 3))
    Sd, L2Sd, T = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    X = np.empty((n, 4))
    n_rhs = 4 if need_cov else 1
    for r0 in range(3):
        for k in range(3):
            c_sum[r0, k] = 0.0
    for i in range(n_frames):
        p = frame_to_pose[i]
        _symmetrized(s_cov[p + 1], tmp)
        if not _spd_inverse(tmp, Ln, Js):
            return i
        _symmetrized(p_cov[i], tmp)
        if not _spd_inverse(tmp, Ln, Jp):
            return i
        _symmetrized(f_cov[p], F)
        for a in range(n):
            ya = 0.0
            for b in range(n):
                Y[a, b] = 0.5 * ((Js[a, b] - Jp[a, b]) + (Js[b, a] - Jp[b, a]))
                ya += Js[a, b] * s_mean[p + 1, b] - Jp[a, b] * p_mean[i, b]
            y[a] = ya
        _rel_disp_jac(s_mean[p, 0], s_mean[p, 1], s_mean[p, 2], s_mean[p + 1, 0] - offset[i, 0],
                      s_mean[p + 1, 1] - offset[i, 1], s_mean[p + 1, 2] - offset[i, 2], L1, L2, m)
        for a in range(3):  # A0 = -L2^T L1 (x_p's pose columns of M), S_d, L2^T S_d
            for b in range(3):
                acc = 0.0
                for k in range(3):
                    acc -= L2[k, a] * L1[k, b]
                A0[a, b] = acc
                Sd[a, b] = cov[a, b] * cov_sd[i, a] * cov_sd[i, b] * cov_scale[i]
        for a in range(3):
            for b in range(3):
                acc = 0.0
                for k in range(3):
                    acc += L2[k, a] * Sd[k, b]
                L2Sd[a, b] = acc
        # u = M m_z + c: pose rows A0 mu_p + L2^T (disp_i - m), bias rows phi b_p
        for a in range(3):
            acc = 0.0
            for k in range(3):
                acc += A0[a, k] * f_mean[p, k] + L2[k, a] * (disp[i, k] - m[k])
            u[a] = acc
        for k in range(K):
            u[3 + k] = phi[i, k] * f_mean[p, 3 + k]
        # S = M P_z M^T: pose block A0 P_pp A0^T + L2^T S_d L2, pose-bias A0 P_pb phi, bias phi P_bb phi + q
        for a in range(3):
            for b in range(3):
                acc = 0.0
                for k in range(3):
                    acc += F[a, k] * A0[b, k]
                T[a, b] = acc  # P_pp A0^T
        for a in range(3):
            for b in range(3):
                acc = 0.0
                for k in range(3):
                    acc += A0[a, k] * T[k, b] + L2Sd[a, k] * L2[k, b]
                S[a, b] = acc
            for j in range(K):
                acc = 0.0
                for k in range(3):
                    acc += A0[a, k] * F[k, 3 + j]
                S[a, 3 + j] = acc * phi[i, j]
                S[3 + j, a] = S[a, 3 + j]
        for j in range(K):
            for k in range(K):
                S[3 + j, 3 + k] = phi[i, j] * F[3 + j, 3 + k] * phi[i, k]
            S[3 + j, 3 + j] += q[i, j]
        # (I + Y S) X = [y - Y u, Y G_d^T], G_d^T = [L2^T S_d; 0]
        for a in range(n):
            ra = y[a]
            for b in range(n):
                ra -= Y[a, b] * u[b]
                acc = 1.0 if a == b else 0.0
                for k in range(n):
                    acc += Y[a, k] * S[k, b]
                A[a, b] = acc
            X[a, 0] = ra
            if need_cov:
                for b in range(3):
                    acc = 0.0
                    for k in range(3):
                        acc += Y[a, k] * L2Sd[k, b]
                    X[a, 1 + b] = acc
        if not _lu_solve(A, X[:, :n_rhs]):
            return i
        for a in range(3):  # mu* = disp + S_d L2 X[:3, 0]; C* = S_d - S_d L2 X[:3, 1:]
            acc = disp[i, a]
            for k in range(3):
                acc += L2Sd[k, a] * X[k, 0]
            mu_star[i, a] = acc
            if not math.isfinite(acc):
                return i
        if need_cov:
            inv_scale = 1.0 / cov_scale[i]
            for a in range(3):
                for b in range(3):
                    cab, cba = Sd[a, b], Sd[b, a]
                    for k in range(3):
                        cab -= L2Sd[k, a] * X[k, 1 + b]
                        cba -= L2Sd[k, b] * X[k, 1 + a]
                    c_sum[a, b] += 0.5 * (cab + cba) * inv_scale / (cov_sd[i, a] * cov_sd[i, b])
    return -1


def displacement_statistics_compiled(lo: Lowered, batch: Batch, post: Posterior, need_cov: bool):
    """Compiled twin of ``augmented.displacement_statistics`` (same contract): mu_star (N, 3) and, if
    ``need_cov``, sum_i D_i^-1 C*_i D_i^-1 / cov_scale_i (``Lowered.whitened``; else None)."""
    ex, ext = post.extra, lo.extra
    n_frames, K = batch.n_frames, ext.k
    n = 3 + K
    mu_star, c_sum = np.empty((n_frames, 3)), np.zeros((3, 3))
    bad = _displacement_kernel(
        np.ascontiguousarray(batch.frame_to_pose, dtype=np.int64), _f64(lo.offset, (n_frames, 3)),
        _f64(lo.disp, (n_frames, 3)), _f64(lo.cov, (3, 3)),
        _f64(np.broadcast_to(lo.cov_scale, (n_frames,))), _f64(lo.cov_sd, (n_frames, 3)), _f64(ext.phi, (n_frames, K)),
        _f64(ext.q, (n_frames, K)),
        _f64(ex.filtered_mean), _f64(ex.filtered_cov), _f64(ex.predicted_mean, (n_frames, n)),
        _f64(ex.predicted_cov, (n_frames, n, n)), _f64(ex.smoothed_mean), _f64(ex.smoothed_cov), need_cov, mu_star, c_sum)
    if bad >= 0:
        raise FloatingPointError(f"action M-step: non-finite statistics at batch frame {bad}")
    return mu_star, (c_sum if need_cov else None)
