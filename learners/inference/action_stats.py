"""Action M-step (paper section III-A; docs/em-math.md "Action M-step"), vectorized over frames.

For frame i (start pose p, end pose p+1) the joint f_alpha,delta over (s_p, s_{p+1}) is
alpha_p (mean mu_alpha,p, cov P_alpha,p) times delta_i (information Y_delta, y_delta),
block-diagonal (eq. (6)). The relative displacement d(s_p, s_{p+1}) = R(-theta_p)(s_{p+1} - s_p)
is linearized at the SMOOTHED means (named choice: mu_delta may not exist):
d ~ L1 s_p + L2 s_{p+1} + m. Its belief under f_alpha,delta, in information form:

    Y' = L2^-T Y_delta L2^-1, y' = L2^-T y_delta    (L2 = R3(-theta) is a rotation: L2^-1 = L2^T)
    P1 = L1 P_alpha,p L1^T, m1 = L1 mu_alpha,p + m
    Y_d = (I + Y' P1)^-1 Y', y_d = (I + Y' P1)^-1 (y' + Y' m1)

multiplied by the previous action model N(mu_hat_A, Sigma_hat_A) (footnote 3):

    C*_i = (Sigma_hat_A^-1 + Y_d)^-1, mu*_i = mu_hat_A + C*_i (y_d - Y_d mu_hat_A).

Units: displacements per frame (mm, mm, rad) in the frame of the start pose.
"""

from __future__ import annotations

import numpy as np

from aibo_core import geometry
from .data import Batch
from .params import ActionModel, Params
from .posterior import Posterior


def _mv(A, v):
    return np.einsum("...ij,...j->...i", A, v)


def _sym(A):
    return 0.5 * (A + np.swapaxes(A, -1, -2))


def action_statistics(params: Params, batch: Batch, post: Posterior):
    """Per-frame posterior of the relative displacement times the previous action model.

    Returns ``mu_star`` (N, 3) and ``C_star`` (N, 3, 3) (mm, mm, rad per frame).
    """
    p = batch.frame_to_pose
    mu_hat = np.asarray(params.action.disp, dtype=float)[batch.actions]  # (N, 3)
    sig_hat = np.asarray(params.action.cov, dtype=float)
    eye = np.eye(3)

    L1, L2, m = geometry.rel_disp_jac(post.mu_gamma[p], post.mu_gamma[p + 1])
    L2T = np.swapaxes(L2, 1, 2)  # = L2^-1 (rotation)
    Yp = _sym(L2 @ post.info_delta @ L2T)  # L2^-T Y_delta L2^-1
    yp = _mv(L2, post.vec_delta)  # L2^-T y_delta
    P1 = L1 @ post.cov_alpha[p] @ np.swapaxes(L1, 1, 2)
    m1 = _mv(L1, post.mu_alpha[p]) + m
    M = eye + Yp @ P1
    rhs = np.concatenate([Yp, (yp + _mv(Yp, m1))[:, :, None]], axis=2)  # (N, 3, 4)
    X = np.linalg.solve(M, rhs)
    Yd = _sym(X[:, :, :3])
    yd = X[:, :, 3]

    C_star = _sym(np.linalg.inv(np.linalg.inv(sig_hat) + Yd))
    mu_star = mu_hat + _mv(C_star, yd - _mv(Yd, mu_hat))
    if not (np.isfinite(mu_star).all() and np.isfinite(C_star).all()):
        bad = int(np.flatnonzero(~np.isfinite(mu_star).all(axis=1) | ~np.isfinite(C_star).all(axis=(1, 2)))[0])
        raise FloatingPointError(f"action M-step: non-finite statistics at batch frame {bad}")
    return mu_star, C_star


def update_action_model(params: Params, batch: Batch, post: Posterior, learn_noise: bool = False) -> ActionModel:
    """New ActionModel: disp[A] = mean of mu*_i over frames with action A (eq. (5)); actions
    never executed keep their previous value. With ``learn_noise`` (a deviation, off in the
    paper) Sigma_A = mean over all frames of C*_i + (mu*_i - mu_A(i))(mu*_i - mu_A(i))^T with
    the NEW means mu_A; otherwise Sigma_A is kept.
    """
    mu_star, C_star = action_statistics(params, batch, post)
    old = np.asarray(params.action.disp, dtype=float)
    n_act = old.shape[0]
    counts = np.bincount(batch.actions, minlength=n_act).astype(float)
    sums = np.stack([np.bincount(batch.actions, weights=mu_star[:, k], minlength=n_act) for k in range(3)], axis=1)
    disp = old.copy()
    seen = counts > 0
    disp[seen] = sums[seen] / counts[seen, None]
    cov = np.array(params.action.cov, dtype=float)
    if learn_noise and len(mu_star):
        r = mu_star - disp[batch.actions]
        cov = _sym(C_star.mean(axis=0) + r.T @ r / len(r))
    return ActionModel(disp, cov, params.action.dt)
