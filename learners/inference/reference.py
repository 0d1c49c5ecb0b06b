"""Plain-NumPy, per-step REFERENCE E-step: forward EKF (alpha), backward information
filter (beta, delta) and their combination (gamma), as specified in docs/em-math.md.

The generic pieces (``ekf_predict`` ... ``combine``, ``forward_pass``, ``backward_pass``,
``two_filter_smooth``) know nothing about the robot: they take a (linearized) model as
callables and a CSR layout of the observations (frame i has observations
``obs_start[i]:obs_start[i+1]``, any number, applied one after the other):

    motion(i, mean)  -> (g, F, Q)            # g = g_i(mean), F = dg_i/ds at mean, Q noise cov
    observe(j, mean) -> None | (h, H, R, z, angle_mask)
                                             # observation j (None: not used): h = h_j(mean),
                                             # H = dh_j/ds, R obs noise cov, z the observation,
                                             # angle_mask marks the components whose innovation
                                             # is wrapped

so a linear-Gaussian system runs through the very same code (tests/test_smoother.py shows
equality with a textbook Kalman filter + RTS smoother). ``smooth`` wires the lowered aibo model
(``Lowered``: per-frame displacement, offset, noise scale; per-sighting size scale/offset/variance
factor and bearing offset; the sensor curve in its basis) into them, log by log.

Deviation (named, see the spec): the log-likelihood uses the full one-step predictive
covariance S = H P- H^T + R_obs, not the paper's J Sigma_alpha,t-1 J^T.

This module is the reference for the compiled twin in ``kernels/estep.py``; it favours clarity
over speed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from aibo_core import geometry
from learners.arrays.batch import Batch
from learners.arrays.lowered import Lowered, sighting_model
from learners.arrays.posterior import Posterior

LOG_2PI = float(np.log(2.0 * np.pi))

#: aibo observation: (size px or mm, bearing rad); only the bearing innovation is wrapped.
AIBO_ANGLE_MASK = np.array([False, True])

MotionFn = Callable[[int, np.ndarray], tuple]
ObserveFn = Callable[[int, np.ndarray], Optional[tuple]]  # (observation index j, mean)


def sym(A: np.ndarray) -> np.ndarray:
    """Symmetric part (A + A^T) / 2 over the last two axes."""
    return 0.5 * (A + np.swapaxes(A, -1, -2))


# --------------------------------------------------------------------------- generic steps


def ekf_predict(P: np.ndarray, g: np.ndarray, F: np.ndarray, Q: np.ndarray):
    """EKF time update from a belief with covariance P, linearized motion (g, F) and noise Q.

    Returns (mu-, P-) = (g, F P F^T + Q), symmetrized.
    """
    return np.array(g, dtype=float), sym(F @ P @ F.T + Q)


def innovation(h: np.ndarray, z: np.ndarray, angle_mask) -> np.ndarray:
    """v = z - h with the components in ``angle_mask`` wrapped to (-pi, pi]."""
    v = np.asarray(z, dtype=float) - h
    if angle_mask is not None and np.any(angle_mask):
        v = np.where(angle_mask, geometry.wrap(v), v)
    return v


def ekf_innovation(P_pred, h, H, R, z, angle_mask):
    """Innovation v (wrapped where ``angle_mask``) and its predictive covariance S = H P- H^T + R."""
    v = innovation(h, z, angle_mask)
    S = sym(H @ P_pred @ H.T + R)
    return v, S


def gaussian_loglik(v: np.ndarray, S: np.ndarray):
    """(log N(v; 0, S), v^T S^-1 v). Raises LinAlgError if S is not positive definite."""
    L = np.linalg.cholesky(S)
    w = np.linalg.solve(L, v)
    mahal2 = float(w @ w)
    logdet = 2.0 * float(np.sum(np.log(np.diag(L))))
    return -0.5 * (mahal2 + logdet + len(v) * LOG_2PI), mahal2


def ekf_update(mu_pred, P_pred, H, R, v, S):
    """EKF measurement update, Joseph form: K = P- H^T S^-1, mu = mu- + K v,
    P = (I - K H) P- (I - K H)^T + K R K^T (symmetrized)."""
    K = np.linalg.solve(S, H @ P_pred).T  # S and P- symmetric
    IKH = np.eye(len(mu_pred)) - K @ H
    P = sym(IKH @ P_pred @ IKH.T + K @ R @ K.T)
    return mu_pred + K @ v, P


def info_observe(Y, y, H, R, v, mu_lin):
    """Backward observation update in information form, h linearized at ``mu_lin``:
    Y_delta = Y + H^T R^-1 H, y_delta = y + H^T R^-1 (v + H mu_lin), v the (wrapped)
    innovation at mu_lin."""
    HtRi = np.linalg.solve(R, H).T
    return sym(Y + HtRi @ H), y + HtRi @ (v + H @ mu_lin)


def info_predict_back(Yd, yd, F, Q, c):
    """Backward time update through s' = F s + c + w, w ~ N(0, Q), of an information-form
    factor (Yd, yd) on s': Ytil = (I + Yd Q)^-1 Yd, ytil = (I + Yd Q)^-1 yd,
    Y = F^T Ytil F, y = F^T (ytil - Ytil c). Exact for Yd = 0 (no information)."""
    n = len(yd)
    M = np.eye(n) + Yd @ Q
    X = np.linalg.solve(M, np.concatenate([Yd, yd[:, None]], axis=1))
    Ytil = sym(X[:, :n])
    ytil = X[:, n]
    return sym(F.T @ Ytil @ F), F.T @ (ytil - Ytil @ c)


def combine(mu_alpha, cov_alpha, Y, y):
    """Combination (eqs. (1)-(2)) of a forward belief N(mu_alpha, A) with an information-form
    backward factor (Y, y); vectorized over leading axes. With M = (I + Y A)^-1:
    mu_gamma = mu_alpha + A M (y - Y mu_alpha), Sigma_gamma = A - A M Y A (symmetrized)."""
    A = np.asarray(cov_alpha, dtype=float)
    n = A.shape[-1]
    M = np.linalg.inv(np.eye(n) + Y @ A)
    AM = A @ M
    r = y - np.einsum("...ij,...j->...i", Y, mu_alpha)
    mu = mu_alpha + np.einsum("...ij,...j->...i", AM, r)
    cov = sym(A - AM @ Y @ A)
    return mu, cov


# --------------------------------------------------------------------------- generic passes


@dataclass
class ForwardResult:
    """Output of ``forward_pass`` over T frames (T + 1 poses) with M observations."""

    mu: np.ndarray  # (T+1, n) filtered means (after all of a frame's applied observations)
    cov: np.ndarray  # (T+1, n, n) filtered covariances
    g: np.ndarray  # (T, n) motion linearization at mu[i]: g_i(mu[i])
    F: np.ndarray  # (T, n, n) Jacobians at mu[i]
    Q: np.ndarray  # (T, n, n) motion noise at mu[i]
    loglik: float  # sum of applied observations' sequential predictive log densities
    mahal2: np.ndarray  # (M,) v^T S^-1 v, NaN where the observation is not used
    applied: np.ndarray  # (M,) bool: the observation was applied (used and not gated)


@dataclass
class SmootherResult:
    forward: ForwardResult
    Y: np.ndarray  # (T+1, n, n) backward information of beta at each pose (Y[T] = 0)
    y: np.ndarray  # (T+1, n)
    Y_delta: np.ndarray  # (T, n, n) information of delta = b(s, o) beta at frame i's end pose
    y_delta: np.ndarray  # (T, n)
    mu: np.ndarray  # (T+1, n) smoothed means
    cov: np.ndarray  # (T+1, n, n) smoothed covariances


def _fail(where: str, i: int, what: str):
    raise FloatingPointError(f"{where}frame {i}: {what}")


def forward_pass(mu0, P0, obs_start, motion: MotionFn, observe: ObserveFn,
                 gate: float | None = None, where: str = "") -> ForwardResult:
    """Forward EKF over ``len(obs_start) - 1`` frames from N(mu0, P0).

    Frame i predicts pose i+1 from pose i (``motion(i, mu_alpha_i)``), then applies its
    observations j = obs_start[i] .. obs_start[i+1]-1 one after the other: ``observe(j, m)``
    is linearized at the CURRENT mean m (after the previous updates of the frame); None means
    "not used". Update in Joseph form. An observation with ``gate is not None and mahal2 > gate``
    is not applied and adds no likelihood term; its mahal2 is still reported. Raises
    FloatingPointError (message starts with ``where`` and names the frame) when a non-finite
    value appears.
    """
    mu0 = np.asarray(mu0, dtype=float)
    obs_start = np.asarray(obs_start, dtype=np.int64)
    n = len(mu0)
    n_frames = len(obs_start) - 1
    n_obs = int(obs_start[-1])
    mu = np.empty((n_frames + 1, n))
    cov = np.empty((n_frames + 1, n, n))
    gs = np.empty((n_frames, n))
    Fs = np.empty((n_frames, n, n))
    Qs = np.empty((n_frames, n, n))
    mahal2 = np.full(n_obs, np.nan)
    applied = np.zeros(n_obs, dtype=bool)
    loglik = 0.0
    mu[0] = mu0
    cov[0] = sym(np.asarray(P0, dtype=float))
    if not (np.isfinite(mu[0]).all() and np.isfinite(cov[0]).all()):
        _fail(where, 0, "non-finite initial state")
    i = 0
    try:
        for i in range(n_frames):
            g, F, Q = motion(i, mu[i])
            gs[i], Fs[i], Qs[i] = g, F, Q
            m, P = ekf_predict(cov[i], g, F, Q)
            for j in range(obs_start[i], obs_start[i + 1]):
                ob = observe(j, m)
                if ob is None:
                    continue
                h, H, R, z, amask = ob
                v, S = ekf_innovation(P, h, H, R, z, amask)
                ll, d2 = gaussian_loglik(v, S)
                if not (np.isfinite(ll) and np.isfinite(d2)):
                    _fail(where, i, f"non-finite innovation {v} / likelihood in the forward pass")
                mahal2[j] = d2
                if gate is None or d2 <= gate:
                    m, P = ekf_update(m, P, H, R, v, S)
                    loglik += ll
                    applied[j] = True
            if not (np.isfinite(m).all() and np.isfinite(P).all()):
                _fail(where, i, "non-finite filtered mean/covariance in the forward pass")
            mu[i + 1] = m
            cov[i + 1] = P
    except np.linalg.LinAlgError as e:
        raise FloatingPointError(f"{where}frame {i}: forward pass: {e}") from e
    return ForwardResult(mu, cov, gs, Fs, Qs, loglik, mahal2, applied)


def observation_information(mu_alpha, observe: ObserveFn, obs_start, applied):
    """Per-frame observation information for the backward pass: the sum over frame i's applied
    observations j of H_j^T R_j^-1 H_j and H_j^T R_j^-1 (v_j + H_j mu_alpha[i+1]), each
    linearized at the frame's FINAL filtered mean mu_alpha[i+1] (v_j the wrapped innovation);
    zero for frames without one. Returns (dY (T,n,n), dy (T,n))."""
    mu_alpha = np.asarray(mu_alpha, dtype=float)
    obs_start = np.asarray(obs_start, dtype=np.int64)
    T = len(obs_start) - 1
    n = mu_alpha.shape[1]
    dY = np.zeros((T, n, n))
    dy = np.zeros((T, n))
    for i in range(T):
        ml = mu_alpha[i + 1]
        for j in range(obs_start[i], obs_start[i + 1]):
            if applied[j]:
                h, H, R, z, amask = observe(int(j), ml)
                dY[i], dy[i] = info_observe(dY[i], dy[i], H, R, innovation(h, z, amask), ml)
    return dY, dy


def backward_pass(mu_alpha, g, F, Q, dY, dy, where: str = ""):
    """Backward information filter, Sigma_beta,T = infinity (Y = 0, y = 0 at the last pose).

    For frame i = T-1 .. 0: observation update Y_delta = Y + dY[i], y_delta = y + dy[i]
    (``observation_information``: all of frame i's applied observations, linearized at
    mu_alpha[i+1]; zero for frames without one), stored as delta for frame i; then the time
    update to pose i through the motion linearized at mu_alpha[i] (``g[i], F[i], Q[i]`` from the
    forward pass, c = g[i] - F[i] mu_alpha[i]).

    Returns (Y (T+1,n,n), y (T+1,n), Y_delta (T,n,n), y_delta (T,n)).
    """
    mu_alpha = np.asarray(mu_alpha, dtype=float)
    T = len(g)
    n = mu_alpha.shape[1]
    Y = np.zeros((T + 1, n, n))
    y = np.zeros((T + 1, n))
    Yd = np.empty((T, n, n))
    yd = np.empty((T, n))
    c_all = g - np.einsum("tij,tj->ti", F, mu_alpha[:-1])
    Yc = np.zeros((n, n))
    yc = np.zeros(n)
    i = T - 1
    try:
        for i in range(T - 1, -1, -1):
            Yc = Yc + dY[i]
            yc = yc + dy[i]
            Yd[i], yd[i] = Yc, yc
            Yc, yc = info_predict_back(Yc, yc, F[i], Q[i], c_all[i])
            Y[i], y[i] = Yc, yc
    except np.linalg.LinAlgError as e:
        raise FloatingPointError(f"{where}frame {i}: backward pass: {e}") from e
    bad = ~(np.isfinite(Yd).all(axis=(1, 2)) & np.isfinite(yd).all(axis=1)
            & np.isfinite(Y[:-1]).all(axis=(1, 2)) & np.isfinite(y[:-1]).all(axis=1))
    if bad.any():
        _fail(where, int(np.flatnonzero(bad)[-1]), "non-finite information in the backward pass")
    return Y, y, Yd, yd


def two_filter_smooth(mu0, P0, obs_start, motion: MotionFn, observe: ObserveFn,
                      gate: float | None = None, where: str = "",
                      obs_info: Callable | None = None) -> SmootherResult:
    """Forward EKF + backward information filter + combination for one sequence of
    ``len(obs_start) - 1`` frames (observations of frame i: ``obs_start[i]:obs_start[i+1]``).

    ``obs_info(mu_alpha, applied) -> (dY, dy)`` may replace the per-observation
    ``observation_information`` loop by an equivalent vectorized computation.
    """
    fw = forward_pass(mu0, P0, obs_start, motion, observe, gate, where)
    if obs_info is None:
        dY, dy = observation_information(fw.mu, observe, obs_start, fw.applied)
    else:
        dY, dy = obs_info(fw.mu, fw.applied)
    Y, y, Yd, yd = backward_pass(fw.mu, fw.g, fw.F, fw.Q, dY, dy, where)
    try:
        mu, cov = combine(fw.mu, fw.cov, Y, y)
    except np.linalg.LinAlgError as e:
        raise FloatingPointError(f"{where}combination: {e}") from e
    bad = ~(np.isfinite(mu).all(axis=1) & np.isfinite(cov).all(axis=(1, 2)))
    if bad.any():
        p = int(np.argmax(bad))
        _fail(where, max(p - 1, 0), f"non-finite smoothed belief at pose {p}")
    return SmootherResult(fw, Y, y, Yd, yd, mu, cov)


# --------------------------------------------------------------------------- the aibo model


def aibo_model(lo: Lowered, batch: Batch, k: int):
    """The lowered aibo model of log k as (obs_start, motion, observe, obs_info) for
    ``two_filter_smooth`` (frame and observation indices local to the log).

    Motion of frame i: g(s) = s + R(theta) disp[i] + offset[i], Q = cov_scale[i] R D_i Sigma_A D_i R^T.
    """
    f0, f1 = int(batch.frame_start[k]), int(batch.frame_start[k + 1])
    s0 = int(batch.sight_start[f0])
    obs_start = batch.sight_start[f0 : f1 + 1] - s0
    disp = lo.disp[f0:f1]
    offset = lo.offset[f0:f1]
    scale = lo.cov_scale[f0:f1]
    sigA = lo.shaped_cov(slice(f0, f1))  # (n, 3, 3) D_i Sigma_A D_i
    n_s = int(obs_start[-1])
    gidx = np.arange(s0, s0 + n_s)  # global sighting indices
    xy = batch.sight_xy[gidx]
    z = batch.sight_value[gidx]
    used = batch.used[gidx]

    def motion(i, mean):
        g, F, R3 = geometry.motion(mean, disp[i])
        return g + offset[i], F, scale[i] * (R3 @ sigA[i] @ R3.T)

    def observe(j, mean):
        if not used[j]:
            return None
        h, H, rd = sighting_model(lo, mean[None], xy[j : j + 1], gidx[j : j + 1])
        return h[0], H[0], np.diag(rd[0]), z[j], AIBO_ANGLE_MASK

    def obs_info(mu_alpha, applied):
        """Vectorized ``observation_information`` for the aibo model (same sums, any order)."""
        T = len(obs_start) - 1
        dY = np.zeros((T, 3, 3))
        dy = np.zeros((T, 3))
        idx = np.flatnonzero(applied)
        if len(idx):
            fr = np.searchsorted(obs_start, idx, side="right") - 1  # local frame of each sighting
            ml = mu_alpha[fr + 1]
            h, H, rd = sighting_model(lo, ml, xy[idx], gidx[idx])
            v = innovation(h, z[idx], AIBO_ANGLE_MASK)
            HtRi = np.swapaxes(H, 1, 2) / rd[:, None, :]  # H^T R^-1, R diagonal
            np.add.at(dY, fr, sym(HtRi @ H))
            np.add.at(dy, fr, np.einsum("tij,tj->ti", HtRi, v + np.einsum("tij,tj->ti", H, ml)))
        return dY, dy

    return obs_start, motion, observe, obs_info


def smooth(lo: Lowered, batch: Batch, gate: float | None = None) -> Posterior:
    """Reference E-step for every log of ``batch`` (see docs/em-math.md, "E-step").

    Log k starts from N(lo.init_mean[k], lo.init_cov[k]). A frame's used sightings are applied in
    order, each linearized at the mean updated by the previous ones. With ``gate``, a used
    sighting whose squared Mahalanobis innovation exceeds ``gate`` is neither applied (forward
    nor backward) nor counted in the likelihood; its mahal2 is still stored, so the caller prunes
    ``batch.used & (post.mahal2 > gate)``. Raises FloatingPointError naming the log and frame if
    a non-finite value appears.
    """
    L = batch.n_logs
    if len(lo.init_mean) != L or len(lo.init_cov) != L:
        raise ValueError(f"lowered model has {len(lo.init_mean)} initial states, batch has {L} logs")
    N = batch.n_frames
    P = N + L
    mu_alpha = np.empty((P, 3))
    cov_alpha = np.empty((P, 3, 3))
    mu_gamma = np.empty((P, 3))
    cov_gamma = np.empty((P, 3, 3))
    info_delta = np.empty((N, 3, 3))
    vec_delta = np.empty((N, 3))
    mahal2 = np.full(batch.n_sightings, np.nan)
    loglik = 0.0
    fstart = batch.frame_start
    pstart = batch.pose_start
    for k in range(L):
        f0, f1 = int(fstart[k]), int(fstart[k + 1])
        p0, p1 = int(pstart[k]), int(pstart[k + 1])
        s0, s1 = int(batch.sight_start[f0]), int(batch.sight_start[f1])
        obs_start, motion_fn, observe_fn, obs_info = aibo_model(lo, batch, k)
        r = two_filter_smooth(lo.init_mean[k], lo.init_cov[k], obs_start, motion_fn, observe_fn, gate,
                              where=f"log {k}, ", obs_info=obs_info)  # fmt: skip
        mu_alpha[p0:p1] = r.forward.mu
        cov_alpha[p0:p1] = r.forward.cov
        mu_gamma[p0:p1] = r.mu
        cov_gamma[p0:p1] = r.cov
        info_delta[f0:f1] = r.Y_delta
        vec_delta[f0:f1] = r.y_delta
        mahal2[s0:s1] = r.forward.mahal2
        loglik += r.forward.loglik
    return Posterior(mu_alpha, cov_alpha, mu_gamma, cov_gamma, info_delta, vec_delta, float(loglik), mahal2)
