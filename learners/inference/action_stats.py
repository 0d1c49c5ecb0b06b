"""Action M-step statistics (paper section III-A; docs/em-math.md "Action M-step"), vectorized.

For frame i (start pose p, end pose p+1) the joint f_alpha,delta over (s_p, s_{p+1}) is
alpha_p (mean mu_alpha,p, cov P_alpha,p) times delta_i (information Y_delta, y_delta),
block-diagonal (eq. (6)). The robot-frame displacement NET OF the world offset,
d(s_p, s_{p+1}) = R(-theta_p)(s_{p+1} - s_p - offset_i) (heading: theta_{p+1} - theta_p - offset_i[2]),
is d_0(s_p, s'') of s'' = s_{p+1} - offset_i, whose delta factor is (Y_delta, y_delta - Y_delta offset_i).
It is linearized at the SMOOTHED means (named choice: mu_delta may not exist):
d ~ L1 s_p + L2 s'' + m. Its belief under f_alpha,delta, in information form:

    Y' = L2^-T Y_delta L2^-1, y' = L2^-T y''         (L2 = R3(-theta) is a rotation: L2^-1 = L2^T)
    P1 = L1 P_alpha,p L1^T, m1 = L1 mu_alpha,p + m
    Y_d = (I + Y' P1)^-1 Y', y_d = (I + Y' P1)^-1 (y' + Y' m1)

multiplied by the frame's prior N(disp_i, cov_scale_i Sigma_A) (footnote 3, with the prior per frame):

    C*_i = ((cov_scale_i Sigma_A)^-1 + Y_d)^-1, mu*_i = disp_i + C*_i (y_d - Y_d disp_i).

Units: displacements per frame (mm, mm, rad) in the frame of the start pose.
"""

from __future__ import annotations

import numpy as np

from aibo_core import geometry
from learners.arrays.batch import Batch
from learners.arrays.lowered import Lowered
from learners.arrays.posterior import Posterior


def _mv(A, v):
    return np.einsum("...ij,...j->...i", A, v)


def _sym(A):
    return 0.5 * (A + np.swapaxes(A, -1, -2))


def action_statistics(lo: Lowered, batch: Batch, post: Posterior, need_cov: bool):
    """Per-frame posterior mean of the displacement (net of the offset) times the frame's prior.

    Returns ``mu_star`` (N, 3) (mm, mm, rad per frame) and, if ``need_cov``, ``C_sum`` (3, 3) =
    sum_i C*_i / cov_scale_i (else None).
    """
    p = batch.frame_to_pose
    mu_hat = np.asarray(lo.disp, dtype=float)  # (N, 3)
    off = np.asarray(lo.offset, dtype=float)
    scale = np.asarray(lo.cov_scale, dtype=float)
    sig_inv = np.linalg.inv(np.asarray(lo.cov, dtype=float))
    eye = np.eye(3)

    L1, L2, m = geometry.rel_disp_jac(post.mu_gamma[p], post.mu_gamma[p + 1] - off)
    L2T = np.swapaxes(L2, 1, 2)  # = L2^-1 (rotation)
    Yp = _sym(L2 @ post.info_delta @ L2T)  # L2^-T Y_delta L2^-1
    yp = _mv(L2, post.vec_delta - _mv(post.info_delta, off))  # L2^-T y''
    P1 = L1 @ post.cov_alpha[p] @ np.swapaxes(L1, 1, 2)
    m1 = _mv(L1, post.mu_alpha[p]) + m
    M = eye + Yp @ P1
    rhs = np.concatenate([Yp, (yp + _mv(Yp, m1))[:, :, None]], axis=2)  # (N, 3, 4)
    X = np.linalg.solve(M, rhs)
    Yd = _sym(X[:, :, :3])
    yd = X[:, :, 3]

    C_star = _sym(np.linalg.inv(sig_inv / scale[:, None, None] + Yd))
    mu_star = mu_hat + _mv(C_star, yd - _mv(Yd, mu_hat))
    if not (np.isfinite(mu_star).all() and np.isfinite(C_star).all()):
        bad = int(np.flatnonzero(~np.isfinite(mu_star).all(axis=1) | ~np.isfinite(C_star).all(axis=(1, 2)))[0])
        raise FloatingPointError(f"action M-step: non-finite statistics at batch frame {bad}")
    C_sum = (C_star / scale[:, None, None]).sum(axis=0) if need_cov else None
    return mu_star, C_sum


def residual_cov(mu_star: np.ndarray, pred: np.ndarray, cov_scale: np.ndarray) -> np.ndarray:
    """sum_i (mu*_i - pred_i)(mu*_i - pred_i)^T / cov_scale_i, (3, 3) (mm^2, mm rad, rad^2 per frame^2)."""
    r = np.asarray(mu_star, dtype=float) - np.asarray(pred, dtype=float)
    return (r / np.asarray(cov_scale, dtype=float)[:, None]).T @ r
