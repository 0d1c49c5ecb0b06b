"""Compiled (numba) twin of the action statistics of an augmented E-step
(``learners.inference.augmented.displacement_statistics``; docs/em-math.md, "Extra states", is the
specification): per frame, the Gaussian over z = (x_p, d, b_{p+1}) of dimension D = 2 n (n = 3 + K)
built from the filtered belief at p, the bias transition, the smoother's information on the end state
and the frame's displacement prior, solved for the displacement's mean and covariance.

The reference does this with batched ``np.linalg.inv`` / ``solve`` on (N, D, D) arrays (125 ms per
call at 9,000 frames with 4 states: 70% of a fit with bias states); here one frame at a time on
preallocated work arrays, every inverse and solve by Cholesky (the matrices are covariances and
information matrices: symmetric positive definite). Equal to the reference to rounding (tests: 1e-9).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from learners.inference.batch import Batch
from learners.inference.kernels.algebra import _f64
from learners.inference.kernels.augmented import _chol_solve, _cholesky
from learners.inference.lowered import Lowered
from learners.inference.posterior import Posterior


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
def _add_mtym(Y, M, r, n, J, rhs):
    """J += M^T Y M and rhs[:, 0] += M^T r, by blocks: M's columns are A = M[:3, :3] on x_p's pose,
    T = M[:3, n:n+3] on d and the identity on b_{p+1} (x_p's bias columns are zero)."""
    K = n - 3
    for a in range(3):
        for b in range(3):
            aya, ayt, tyt = 0.0, 0.0, 0.0
            for u in range(3):
                for v in range(3):
                    yuv = Y[u, v]
                    aya += M[u, a] * yuv * M[v, b]
                    ayt += M[u, a] * yuv * M[v, n + b]
                    tyt += M[u, n + a] * yuv * M[v, n + b]
            J[a, b] += aya
            J[a, n + b] += ayt
            J[n + b, a] += ayt
            J[n + a, n + b] += tyt
        for k in range(K):
            ayb, tyb = 0.0, 0.0
            for u in range(3):
                ayb += M[u, a] * Y[u, 3 + k]
                tyb += M[u, n + a] * Y[u, 3 + k]
            J[a, n + 3 + k] += ayb
            J[n + 3 + k, a] += ayb
            J[n + a, n + 3 + k] += tyb
            J[n + 3 + k, n + a] += tyb
        ha, hd = 0.0, 0.0
        for u in range(3):
            ha += M[u, a] * r[u]
            hd += M[u, n + a] * r[u]
        rhs[a, 0] += ha
        rhs[n + a, 0] += hd
    for k in range(K):
        for j in range(K):
            J[n + 3 + k, n + 3 + j] += Y[3 + k, 3 + j]
        rhs[n + 3 + k, 0] += r[3 + k]


@njit(cache=True, error_model="numpy")
def _displacement_kernel(frame_to_pose, offset, disp, cov_inv, cov_scale, phi, q, f_mean, f_cov, p_mean, p_cov,
                         s_mean, s_cov, need_cov, mu_star, c_sum):
    """Fills mu_star (N, 3) and c_sum (3, 3); returns -1, or the first frame whose statistics are not finite
    or whose matrices are not positive definite."""
    n_frames = disp.shape[0]
    n = f_mean.shape[1]
    K = n - 3
    D = 2 * n
    Ln, tmp = np.empty((n, n)), np.empty((n, n))
    Js, Jp, Ja, Y = np.empty((n, n)), np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
    y, c, r = np.empty(n), np.empty(n), np.empty(n)
    L1, L2, m = np.empty((3, 3)), np.empty((3, 3)), np.empty(3)
    M = np.zeros((n, D))
    J, LD, rhs = np.empty((D, D)), np.empty((D, D)), np.empty((D, 4))
    for k in range(K):
        M[3 + k, n + 3 + k] = 1.0
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
        _symmetrized(f_cov[p], tmp)
        if not _spd_inverse(tmp, Ln, Ja):
            return i
        for a in range(n):
            ya = 0.0
            for b in range(n):
                Y[a, b] = 0.5 * ((Js[a, b] - Jp[a, b]) + (Js[b, a] - Jp[b, a]))
                ya += Js[a, b] * s_mean[p + 1, b] - Jp[a, b] * p_mean[i, b]
            y[a] = ya
        _rel_disp_jac(s_mean[p, 0], s_mean[p, 1], s_mean[p, 2], s_mean[p + 1, 0] - offset[i, 0],
                      s_mean[p + 1, 1] - offset[i, 1], s_mean[p + 1, 2] - offset[i, 2], L1, L2, m)
        # M z + c = (s_{p+1} - offset, b_{p+1}): pose rows -L2^T L1 | L2^T, bias rows I (set once)
        for a in range(3):
            for b in range(3):
                acc = 0.0
                for k in range(3):
                    acc -= L2[k, a] * L1[k, b]
                M[a, b] = acc
                M[a, n + b] = L2[b, a]
            c[a] = -(L2[0, a] * m[0] + L2[1, a] * m[1] + L2[2, a] * m[2])
        for a in range(3, n):
            c[a] = 0.0
        # J, h: the filtered belief at p, the bias transition, the end-state information, the prior
        for a in range(D):
            for b in range(D):
                J[a, b] = 0.0
            rhs[a, 0] = 0.0
        for a in range(n):
            ha = 0.0
            for b in range(n):
                J[a, b] = Ja[a, b]
                ha += Ja[a, b] * f_mean[p, b]
            rhs[a, 0] = ha
        for k in range(K):
            w = 1.0 / q[i, k]
            J[3 + k, 3 + k] += phi[i, k] ** 2 * w
            J[n + 3 + k, n + 3 + k] += w
            J[3 + k, n + 3 + k] -= phi[i, k] * w
            J[n + 3 + k, 3 + k] -= phi[i, k] * w
        for a in range(n):  # r = y - Y c
            ra = y[a]
            for b in range(n):
                ra -= Y[a, b] * c[b]
            r[a] = ra
        _add_mtym(Y, M, r, n, J, rhs)
        inv_scale = 1.0 / cov_scale[i]
        for a in range(3):
            ha = 0.0
            for b in range(3):
                J[n + a, n + b] += cov_inv[a, b] * inv_scale
                ha += cov_inv[a, b] * inv_scale * disp[i, b]
            rhs[n + a, 0] += ha
        for a in range(D):
            for b in range(1, 4):
                rhs[a, b] = 1.0 if a == n + b - 1 else 0.0
        for a in range(D):  # symmetrized, as the reference's sym(J)
            for b in range(a + 1, D):
                v = 0.5 * (J[a, b] + J[b, a])
                J[a, b] = v
                J[b, a] = v
        if not _cholesky(J, LD):
            return i
        _chol_solve(LD, rhs)
        for a in range(3):
            mu_star[i, a] = rhs[n + a, 0]
            if not math.isfinite(mu_star[i, a]):
                return i
        if need_cov:
            for a in range(3):
                for b in range(3):
                    c_sum[a, b] += 0.5 * (rhs[n + a, 1 + b] + rhs[n + b, 1 + a]) * inv_scale
    return -1


def displacement_statistics_compiled(lo: Lowered, batch: Batch, post: Posterior, need_cov: bool):
    """Compiled twin of ``augmented.displacement_statistics`` (same contract): mu_star (N, 3) and, if
    ``need_cov``, sum_i C*_i / cov_scale_i (else None)."""
    ex, ext = post.extra, lo.extra
    n_frames, K = batch.n_frames, ext.k
    n = 3 + K
    mu_star, c_sum = np.empty((n_frames, 3)), np.zeros((3, 3))
    bad = _displacement_kernel(
        np.ascontiguousarray(batch.frame_to_pose, dtype=np.int64), _f64(lo.offset, (n_frames, 3)),
        _f64(lo.disp, (n_frames, 3)), np.linalg.inv(np.asarray(lo.cov, dtype=float)),
        _f64(np.broadcast_to(lo.cov_scale, (n_frames,))), _f64(ext.phi, (n_frames, K)), _f64(ext.q, (n_frames, K)),
        _f64(ex.filtered_mean), _f64(ex.filtered_cov), _f64(ex.predicted_mean, (n_frames, n)),
        _f64(ex.predicted_cov, (n_frames, n, n)), _f64(ex.smoothed_mean), _f64(ex.smoothed_cov), need_cov, mu_star, c_sum)
    if bad >= 0:
        raise FloatingPointError(f"action M-step: non-finite statistics at batch frame {bad}")
    return mu_star, (c_sum if need_cov else None)
