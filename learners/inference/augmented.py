"""Plain-NumPy REFERENCE E-step with extra states beside the pose (``Lowered.extra``), and the M-step
statistics that read its output. The compiled twin is ``kernels/augmented.py``; docs/em-math.md,
"Extra states", is the specification.

The state is x = (s, b): the pose s = (x mm, y mm, theta rad) and K scalar states b (e.g. per-landmark
relative size biases). Frame i moves s as the base model does and each b_k by its AR(1) step,
b_k' = phi[i, k] b_k + N(0, q[i, k]); a sighting j with slot k = extra.slot[j] >= 0 measures

    size = size_scale[j] f(d) (1 + b_k) + size_offset[j] + e1,   bearing as in the base model,

so its Jacobian row 0 is (1 + b_k) times the base one on the pose, and size_scale[j] f(d) on b_k; a sighting with
a bearing state k' = extra.bearing_slot[j] >= 0 measures bearing + b_k' (its Jacobian row 1 has 1 on b_k').
Inference is a forward EKF on x (the base model's conventions: heading unwrapped, bearing innovations
wrapped, a frame's sightings applied in order, Joseph form, gating) and a Rauch-Tung-Striebel
backward pass, which gives the lag-one cross-covariances the M-steps need:

    G_p = P_p F_p^T (P-_{p+1})^-1,   m_p = mu_p + G_p (m_{p+1} - g_p(mu_p)),
    C_p = P_p + G_p (C_{p+1} - P-_{p+1}) G_p^T,   Cov(x_p, x_{p+1} | all) = G_p C_{p+1}.

(The base model keeps the paper's two-filter smoother; both are exact for a linear-Gaussian model.)
"""

from __future__ import annotations

import numpy as np

from aibo_core import geometry
from learners.arrays.batch import Batch
from learners.arrays.displacement import augmented_displacement_beliefs
from learners.arrays.innovations import joint_belief
from learners.arrays.lowered import Lowered, sighting_model
from learners.arrays.posterior import ExtraMoments, Posterior

from .reference import AIBO_ANGLE_MASK, ForwardResult, forward_pass, sym


def rts_pass(fw: ForwardResult, where: str = "") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rauch-Tung-Striebel backward pass over a ``forward_pass`` (module docstring): smoothed means
    (T+1, n), covariances (T+1, n, n) and the lag-one cross-covariances Cov(x_i, x_{i+1}) (T, n, n)."""
    T = len(fw.g)
    mu = fw.mu.copy()
    cov = fw.cov.copy()
    cross = np.empty((T,) + fw.cov.shape[1:])
    i = T - 1
    try:
        for i in range(T - 1, -1, -1):
            F = fw.F[i]
            P_pred = sym(F @ fw.cov[i] @ F.T + fw.Q[i])
            G = np.linalg.solve(P_pred, F @ fw.cov[i]).T  # P F^T P-^-1 (P, P- symmetric)
            mu[i] = fw.mu[i] + G @ (mu[i + 1] - fw.g[i])
            cov[i] = sym(fw.cov[i] + G @ (cov[i + 1] - P_pred) @ G.T)
            cross[i] = G @ cov[i + 1]
    except np.linalg.LinAlgError as e:
        raise FloatingPointError(f"{where}frame {i}: backward (RTS) pass: {e}") from e
    if not (np.isfinite(mu).all() and np.isfinite(cov).all()):
        raise FloatingPointError(f"{where}non-finite smoothed belief in the backward (RTS) pass")
    return mu, cov, cross


def augmented_model(lo: Lowered, batch: Batch, k: int):
    """The lowered model of log k on the augmented state, as (obs_start, motion, observe) for
    ``forward_pass`` (frame and observation indices local to the log)."""
    ex = lo.extra
    K = ex.k
    n = 3 + K
    f0, f1 = int(batch.frame_start[k]), int(batch.frame_start[k + 1])
    s0 = int(batch.sight_start[f0])
    obs_start = batch.sight_start[f0 : f1 + 1] - s0
    disp, offset, scale = lo.disp[f0:f1], lo.offset[f0:f1], lo.cov_scale[f0:f1]
    phi, q = ex.phi[f0:f1], ex.q[f0:f1]
    sigA = lo.shaped_cov(slice(f0, f1))  # (n, 3, 3) D_i Sigma_A D_i
    gidx = np.arange(s0, s0 + int(obs_start[-1]))
    xy, z, used = batch.sight_xy[gidx], batch.sight_value[gidx], batch.used[gidx]

    def motion(i, mean):
        g3, F3, R3 = geometry.motion(mean[:3], disp[i])
        F = np.zeros((n, n))
        F[:3, :3] = F3
        F[3:, 3:] = np.diag(phi[i])
        Q = np.zeros((n, n))
        Q[:3, :3] = scale[i] * (R3 @ sigA[i] @ R3.T)
        Q[3:, 3:] = np.diag(q[i])
        return np.concatenate([g3 + offset[i], phi[i] * mean[3:]]), F, Q

    def observe(j, mean):
        if not used[j]:
            return None
        h, H3, rd = sighting_model(lo, mean[None, :3], xy[j : j + 1], gidx[j : j + 1])
        h = h[0].copy()
        H = np.zeros((2, n))
        H[:, :3] = H3[0]
        slot = int(ex.slot[gidx[j]])
        if slot >= 0:
            m = 1.0 + mean[3 + slot]
            curve = h[0] - lo.size_offset[gidx[j]]  # size_scale f(d)
            h[0] = curve * m + lo.size_offset[gidx[j]]
            H[0, :3] *= m
            H[0, 3 + slot] = curve
        bslot = int(ex.bearing_slot[gidx[j]])
        if bslot >= 0:  # a bearing bias state: added to the predicted bearing
            h[1] += mean[3 + bslot]
            H[1, 3 + bslot] = 1.0
        return h, H, np.diag(rd[0]), z[j], AIBO_ANGLE_MASK

    return obs_start, motion, observe


def smooth_augmented(lo: Lowered, batch: Batch, gate: float | None = None) -> Posterior:
    """Reference E-step on the augmented state for every log of ``batch`` (module docstring): the pose
    marginals in the Posterior's usual arrays (delta not formed), the whole beliefs in ``Posterior.extra``.
    Each log starts from N((init_mean, 0), blockdiag(init_cov, diag(extra.init_var))). Gating as
    ``reference.smooth``."""
    ex = lo.extra
    L, N, K = batch.n_logs, batch.n_frames, ex.k
    n, P = 3 + K, N + L
    fm, fc, sm, sc = np.empty((P, n)), np.empty((P, n, n)), np.empty((P, n)), np.empty((P, n, n))
    pm, pc, cross = np.empty((N, n)), np.empty((N, n, n)), np.empty((N, K))
    mahal2 = np.full(batch.n_sightings, np.nan)
    loglik = 0.0
    for k in range(L):
        f0, f1 = int(batch.frame_start[k]), int(batch.frame_start[k + 1])
        p0, p1 = int(batch.pose_start[k]), int(batch.pose_start[k + 1])
        s0, s1 = int(batch.sight_start[f0]), int(batch.sight_start[f1])
        obs_start, motion, observe = augmented_model(lo, batch, k)
        m0 = np.concatenate([lo.init_mean[k], np.zeros(K)])
        P0 = np.zeros((n, n))
        P0[:3, :3] = lo.init_cov[k]
        P0[3:, 3:] = np.diag(ex.init_var[k])
        fw = forward_pass(m0, P0, obs_start, motion, observe, gate, where=f"log {k}, ")
        mu, cov, cr = rts_pass(fw, where=f"log {k}, ")
        fm[p0:p1], fc[p0:p1], sm[p0:p1], sc[p0:p1] = fw.mu, fw.cov, mu, cov
        pm[f0:f1] = fw.g
        pc[f0:f1] = sym(fw.F @ fw.cov[:-1] @ np.swapaxes(fw.F, 1, 2) + fw.Q)
        cross[f0:f1] = np.diagonal(cr[:, 3:, 3:], axis1=1, axis2=2)
        mahal2[s0:s1] = fw.mahal2
        loglik += fw.loglik
    return posterior(ExtraMoments(fm, fc, pm, pc, sm, sc, cross), float(loglik), mahal2)


def posterior(extra: ExtraMoments, loglik: float, mahal2: np.ndarray) -> Posterior:
    """The Posterior of an augmented E-step: the pose marginals of its beliefs, and the beliefs."""
    return Posterior(extra.filtered_mean[:, :3].copy(), extra.filtered_cov[:, :3, :3].copy(),
                     extra.smoothed_mean[:, :3].copy(), extra.smoothed_cov[:, :3, :3].copy(), None, None, loglik,
                     mahal2, extra)


# --------------------------------------------------------------------------- M-step statistics


def displacement_statistics(lo: Lowered, batch: Batch, post: Posterior, need_cov: bool):
    """The action statistics of an augmented E-step, twin of ``action_stats.action_statistics`` (the same
    formula on the whole state; docs/em-math.md, "Extra states"): the posterior of the robot-frame
    displacement net of the offset, d = d_0(s_p, s_{p+1} - offset_i), linearized at the smoothed means, from

        alpha_p(x_p)  x  N(b_{p+1}; phi b_p, q)  x  delta_i(x_{p+1})  x  N(d; disp_i, Sigma_i),

    delta_i the information of frame i's and later sightings on its end state, read off the smoother as
    (C_{p+1}^-1 - (P-)^-1, C_{p+1}^-1 m_{p+1} - (P-)^-1 g). (d_0 of the smoothed means themselves is NOT
    it: the smoothed path inherits the forward filter's linearization of the motion at the filtered
    heading, and EM on it lowered the likelihood by ~1 nat per iteration.) Returns mu_star (N, 3) and,
    if ``need_cov``, sum_i D_i^-1 C*_i D_i^-1 / cov_scale_i (``Lowered.whitened``)."""
    mu_star, C = augmented_displacement_beliefs(lo, batch, post)
    if not need_cov:
        return mu_star, None
    return mu_star, lo.whitened(C).sum(axis=0)


def _mv(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.einsum("...ij,...j->...i", A, v)


def sensor_update_augmented(lo: Lowered, batch: Batch, post: Posterior, degree: int):
    """The sensor M-step of an augmented E-step (twin of ``sensor_stats.update_sensor_curve`` with the cubature
    method): the expectations are over each sighting's JOINT smoothed belief of (pose, its size state b), by the
    8 cubature points (m, C) +- sqrt(4) L e_j of that 4-d Gaussian (L = chol C), so that the fit sees the strong
    posterior correlation of b with the distance (a size measured larger is a nearer landmark or a larger bias;
    taken as independent, sigma_size came out ~7 % high and the likelihood fell). Sightings without a state
    get b = 0 (a 1e-24 variance keeps L defined). With bearing states (``ExtraStates.bearing_slot``) the belief is
    5-d, (pose, b, c), by its 10 points, and c is added to the predicted bearing. Least squares of (size - size_offset) on
    size_scale (1 + b) phi(x) at the points, weights 1 / size_var_factor; sigma_size^2, sigma_bearing^2 the
    weighted mean squared residuals. One NumPy implementation for both paths (the E-step is the compiled one).
    Returns (coef, sigma_size, sigma_bearing, (dmin, dmax) mm at the smoothed means)."""
    from learners.arrays.lowered import fit_polynomial

    from .sensor_stats import basis_variable

    idx = np.flatnonzero(batch.used)
    p = batch.sight_pose[idx]
    mean, C = joint_belief(lo, post, idx, p, smoothed=True)  # (pose, size bias, bearing bias)
    dim = 5 if np.any(lo.extra.bearing_slot[idx] >= 0) else 4  # without bearing states: the 4-d rule as before
    mean, C = mean[:, :dim], C[:, :dim, :dim]
    for e in range(3, dim):
        none = C[:, e, e] == 0.0
        C[none, e, e] = 1e-24
    try:
        L = np.linalg.cholesky(sym(C))
    except np.linalg.LinAlgError as e:
        raise FloatingPointError(f"sensor M-step: smoothed covariance not positive definite: {e}") from e
    sL = np.sqrt(dim) * np.swapaxes(L, 1, 2)  # row j = sqrt(dim) L e_j
    pts = np.concatenate([mean[:, None, :] + sL, mean[:, None, :] - sL], axis=1).reshape(-1, dim)  # (2 dim n, dim)
    sight = np.repeat(idx, 2 * dim)
    dx, dy = batch.sight_xy[sight, 0] - pts[:, 0], batch.sight_xy[sight, 1] - pts[:, 1]
    dist = np.hypot(dx, dy)
    bearing = geometry.wrap(np.arctan2(dy, dx) - pts[:, 2] + lo.bearing_offset[sight] + (pts[:, 4] if dim == 5 else 0.0))
    x = basis_variable(lo.basis, dist)
    scale = lo.size_scale[sight] * (1.0 + pts[:, 3])
    size, off, vf = batch.sight_value[sight, 0], lo.size_offset[sight], lo.size_var_factor[sight]
    w = np.full(len(sight), 1.0 / (2 * dim))
    coef = fit_polynomial(x, size - off, w / vf, degree, scale=scale)
    res_s = scale * np.polynomial.polynomial.polyval(x, coef) + off - size
    res_b = geometry.wrap(bearing - batch.sight_value[sight, 1])
    wsum = w.sum()
    sigma_s = float(np.sqrt(np.sum(w * res_s**2 / vf) / wsum))
    sigma_b = float(np.sqrt(np.sum(w * res_b**2 / lo.bearing_var_factor[sight]) / wsum))
    dm = np.hypot(batch.sight_xy[idx, 0] - post.mu_gamma[p, 0], batch.sight_xy[idx, 1] - post.mu_gamma[p, 1])
    return coef, sigma_s, sigma_b, (float(dm.min()), float(dm.max()))


def size_factor_moments(lo: Lowered, batch: Batch, post: Posterior) -> tuple[np.ndarray, np.ndarray]:
    """(S,) smoothed mean and variance of each sighting's size factor m = 1 + b (1 and 0 without a state)."""
    mean, var = np.ones(batch.n_sightings), np.zeros(batch.n_sightings)
    if lo.extra is None or post.extra is None:
        return mean, var
    j = np.flatnonzero(lo.extra.slot >= 0)
    pose, slot = batch.sight_pose[j], lo.extra.slot[j]
    mean[j] = 1.0 + post.extra.mean[pose, slot]
    var[j] = post.extra.var[pose, slot]
    return mean, var
