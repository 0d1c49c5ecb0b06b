"""Each frame's belief of its displacement under its motion prior: what the action M-step
(``learners.inference.action_stats``, ``learners.inference.augmented``) sums and what an effect on the motion's noise
(``learners.model.turn_noise``) reads frame by frame (docs/em-math.md, "Action M-step").

For frame i (start pose p, end pose p+1) the robot-frame displacement net of the world offset,
d(s_p, s_{p+1}) = R(-theta_p)(s_{p+1} - s_p - offset_i) (heading: theta_{p+1} - theta_p - offset_i[2]), linearized at
the smoothed means, has the belief N(mu*_i, C*_i) that combines the E-step's information on the two poses (the forward
filter's alpha_p and the backward information delta_i on the end pose) with the frame's prior N(disp_i, cov_scale_i
Sigma_A). The formulas are ``action_stats``' (pose only) and ``augmented``'s (extra states beside the pose).
Units: mm, mm, rad per frame, in the frame of the start pose.
"""

from __future__ import annotations

import numpy as np

from aibo_core import geometry
from learners.arrays.batch import Batch
from learners.arrays.lowered import Lowered
from learners.arrays.posterior import Posterior


def displacement_beliefs(lo: Lowered, batch: Batch, post: Posterior) -> tuple[np.ndarray, np.ndarray]:
    """(mu*_i (N, 3), C*_i (N, 3, 3)) of every frame: the augmented formula where the E-step carried extra states."""
    if post.extra is not None:
        return augmented_displacement_beliefs(lo, batch, post)
    return pose_displacement_beliefs(lo, batch, post)


def pose_displacement_beliefs(lo: Lowered, batch: Batch, post: Posterior) -> tuple[np.ndarray, np.ndarray]:
    """(mu*_i (N, 3), C*_i (N, 3, 3)): each frame's belief of its displacement (net of the offset) under its prior
    N(disp_i, Sigma_i) (``Lowered.frame_cov``) and the E-step's information on its poses (module docstring); an effect on the
    motion noise (``turn_dependent_noise``) takes its expected second moments from them."""
    p = batch.frame_to_pose
    mu_hat = np.asarray(lo.disp, dtype=float)  # (N, 3)
    off = np.asarray(lo.offset, dtype=float)
    prior = lo.whitened(np.broadcast_to(np.linalg.inv(np.asarray(lo.cov, dtype=float)), (len(mu_hat), 3, 3)))
    eye = np.eye(3)

    L1, L2, m = geometry.rel_disp_jac(post.mu_gamma[p], post.mu_gamma[p + 1] - off)
    L2T = np.swapaxes(L2, 1, 2)  # = L2^-1 (rotation)
    Yp = _symmetric(L2 @ post.info_delta @ L2T)  # L2^-T Y_delta L2^-1
    yp = _mv(L2, post.vec_delta - _mv(post.info_delta, off))  # L2^-T y''
    P1 = L1 @ post.cov_alpha[p] @ np.swapaxes(L1, 1, 2)
    m1 = _mv(L1, post.mu_alpha[p]) + m
    M = eye + Yp @ P1
    rhs = np.concatenate([Yp, (yp + _mv(Yp, m1))[:, :, None]], axis=2)  # (N, 3, 4)
    X = np.linalg.solve(M, rhs)
    Yd = _symmetric(X[:, :, :3])
    yd = X[:, :, 3]

    C_star = _symmetric(np.linalg.inv(prior + Yd))  # prior: Sigma_i^-1
    mu_star = mu_hat + _mv(C_star, yd - _mv(Yd, mu_hat))
    if not (np.isfinite(mu_star).all() and np.isfinite(C_star).all()):
        bad = int(np.flatnonzero(~np.isfinite(mu_star).all(axis=1) | ~np.isfinite(C_star).all(axis=(1, 2)))[0])
        raise FloatingPointError(f"action M-step: non-finite statistics at batch frame {bad}")
    return mu_star, C_star


def augmented_displacement_beliefs(lo: Lowered, batch: Batch, post: Posterior) -> tuple[np.ndarray, np.ndarray]:
    """(mu*_i (N, 3), C*_i (N, 3, 3)) of an augmented E-step: each frame's belief of its displacement (net of the
    offset) under its prior (``displacement_statistics``' formula), twin of ``pose_displacement_beliefs``."""
    ex, ext = post.extra, lo.extra
    K = ext.k
    n, N = 3 + K, batch.n_frames
    D = n + 3 + K  # z = (x_p, d, b_{p+1})
    p = batch.frame_to_pose
    inv = np.linalg.inv
    Js, Jp = inv(ex.smoothed_cov[p + 1]), inv(ex.predicted_cov)
    Y = _symmetric(Js - Jp)
    y = _mv(Js, ex.smoothed_mean[p + 1]) - _mv(Jp, ex.predicted_mean)
    L1, L2, m = geometry.rel_disp_jac(ex.smoothed_mean[p, :3], ex.smoothed_mean[p + 1, :3] - lo.offset)
    L2T = np.swapaxes(L2, 1, 2)
    M = np.zeros((N, n, D))  # (s_{p+1} - offset, b_{p+1}) = M z + c
    M[:, :3, :3] = -L2T @ L1
    M[:, :3, n:n + 3] = L2T
    M[:, 3:, n + 3:] = np.eye(K)
    c = np.zeros((N, n))
    c[:, :3] = -_mv(L2T, m)
    J, h = np.zeros((N, D, D)), np.zeros((N, D))
    Ja = inv(ex.filtered_cov[p])
    J[:, :n, :n] = Ja
    h[:, :n] = _mv(Ja, ex.filtered_mean[p])
    w = 1.0 / ext.q
    bp, bn = 3 + np.arange(K), n + 3 + np.arange(K)
    J[:, bp, bp] += ext.phi ** 2 * w
    J[:, bn, bn] += w
    J[:, bp, bn] -= ext.phi * w
    J[:, bn, bp] -= ext.phi * w
    MT = np.swapaxes(M, 1, 2)
    J += MT @ Y @ M
    h += _mv(MT, y - _mv(Y, c))
    prior = lo.whitened(np.broadcast_to(inv(np.asarray(lo.cov, dtype=float)), (N, 3, 3)))  # Sigma_i^-1
    J[:, n:n + 3, n:n + 3] += prior
    h[:, n:n + 3] += _mv(prior, lo.disp)
    rhs = np.zeros((N, D, 4))
    rhs[:, :, 0] = h
    rhs[:, n:n + 3, 1:] = np.eye(3)
    X = np.linalg.solve(_symmetric(J), rhs)
    mu_star = X[:, n:n + 3, 0]
    if not np.isfinite(mu_star).all():
        bad = int(np.flatnonzero(~np.isfinite(mu_star).all(axis=1))[0])
        raise FloatingPointError(f"action M-step: non-finite statistics at batch frame {bad}")
    return mu_star, _symmetric(X[:, n:n + 3, 1:])


def _mv(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.einsum("...ij,...j->...i", A, v)


def _symmetric(A: np.ndarray) -> np.ndarray:
    return 0.5 * (A + np.swapaxes(A, -1, -2))
