"""Compiled (numba) twin of the E-step: ``_smooth_kernel`` and its wrapper ``smooth_compiled``.

Same contract and equations as the plain-NumPy reference ``reference.smooth`` on the lowered arrays
(``Lowered``: per-frame disp / offset / cov_scale, per-sighting size_scale / size_offset /
size_var_factor / bearing_offset, the sensor curve in its basis); docs/em-math.md is the
specification. Conventions match the reference:
- heading unwrapped in every mean; innovations wrapped to (-pi, pi];
- a frame's used sightings applied one after the other (CSR ``sight_start``), each linearized at
  the current mean; Joseph-form update; full one-step predictive S for the likelihood and mahal2;
- backward information filter from Y = 0, y = 0 at each log's last pose, linearized at the
  forward filtered means; combination into gamma in information form;
- covariances (and Y) symmetrized.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from learners.arrays.batch import Batch
from learners.arrays.lowered import Lowered
from learners.arrays.posterior import Posterior
from learners.inference.kernels.algebra import (
    _BAD_BACKWARD,
    _BAD_FORWARD,
    _BAD_GAMMA,
    _LOG_2PI,
    _OK,
    _ZERO3,
    _ZERO33,
    _add,
    _fin3,
    _fin33,
    _inv_i_plus,
    _ld3,
    _ld33,
    _mm,
    _mv,
    _raise,
    _scratch,
    _st3,
    _st33,
    _sym,
    _wrap,
)
from learners.inference.kernels.arguments import kernel_inputs
from learners.inference.kernels.augmented import innovations_augmented_compiled, smooth_augmented_compiled
from learners.inference.kernels.fasttrig import _cos_sin
from learners.inference.kernels.structured import (
    _FMA,
    _combine_fast,
    _dscale_sym,
    _fpft_sym,
    _ftyf_sym,
    _observe_h,
    _rot_sym,
    _symm,
)

# ----------------------------------------------------------------------------------------------
# Speed notes (the equations are docs/em-math.md's; only rounding differs from the reference):
# - cos/sin of each forward filtered heading are computed once (``_cos_sin``) and kept in a
#   scratch array: the backward time update linearizes g at the same mu_alpha, so it rebuilds
#   F, Q and c = g - F mu from them without any trig;
# - bearings use the branch-free ``_atan2`` (<= 3 ulp);
# - F = I + (column 2) and Q = cov_scale R D Sigma_A D R^T (Sigma_A symmetrized once) are applied
#   through their structure; symmetric results (P, Y, Q, Ytil, Sigma_gamma) are formed from their
#   upper triangle, which replaces the symmetrization (same matrix up to rounding);
# - H has the constant entries H[0,2] = 0, H[1,2] = -1, written out (x * 0.0 is not folded);
# - the backward observation information (sum over the frame's applied sightings of H^T R^-1 H,
#   H^T R^-1 (v + H mu) at mu_alpha[i+1]) is computed by the forward pass right after that mean is
#   known (off its serial chain) and parked in info_delta[i] / vec_delta[i] (zero where no
#   sighting is applied); the backward pass adds it and overwrites the slot with Y_delta, y_delta;
# - combination: A - A M Y A = A M exactly (A M (I + Y A) = A), so Sigma_gamma = sym(A M);
# - the E-step's own functions may fuse a * b + c into one FMA (``_FMA``): fewer instructions on
#   the forward pass's serial chain, rounding-level differences only;
# - offsets (+ 0.0) and scales (* 1.0) are exact, so a model without effects gives the numbers of
#   the table-indexed kernel it replaces: the forward pass (alpha, mahal2, loglik) bit for bit; the
#   backward pass and gamma bit for bit with a diagonal Sigma_A, to ~1e-13 relative otherwise.


class SmoothOutputs(NamedTuple):
    """The E-step kernel's output arrays (overwritten) and its scratch; P poses, N frames, S sightings."""

    mu_alpha: np.ndarray  # (P, 3) mm, mm, rad: forward filtered means (heading unwrapped)
    cov_alpha: np.ndarray  # (P, 3, 3)
    mu_gamma: np.ndarray  # (P, 3): smoothed means (unset with forward_only)
    cov_gamma: np.ndarray  # (P, 3, 3)
    info_delta: np.ndarray  # (N, 3, 3): each frame's observation information, then Y_delta
    vec_delta: np.ndarray  # (N, 3): its vector, then y_delta
    mahal2: np.ndarray  # (S,): squared Mahalanobis distance of each used sighting's innovation (NaN otherwise)
    innov: np.ndarray  # (S, 5) [v_size, v_bearing, S00, S01, S11] per applied sighting (NaN otherwise); (0, 5): not stored
    cos_th: np.ndarray  # (P,) scratch: cos of mu_alpha[:, 2] (every pose but each log's last), for the backward pass
    sin_th: np.ndarray  # (P,) scratch: its sin


@njit(cache=True, error_model="numpy", fastmath=_FMA, inline="always")
def _forward_log(k, f0, ps, n, fr, si, sig, out, loglik):
    """Forward EKF of log k (frames f0 .. f0+n-1, poses ps .. ps+n) from its initial belief: the filtered
    beliefs, each used sighting's mahal2 (and innovation when ``out.innov`` has S rows), and the backward
    observation information of each frame parked in ``out.info_delta`` / ``out.vec_delta``.
    Returns (status, frame index within the log, loglik + this log's log-likelihood). With one-row
    ``out.mu_alpha`` (``innovations_compiled``: the forward pass alone) nothing per pose or per frame is
    stored (no filtered beliefs, cos/sin, backward observation information): the innovations and loglik
    are the same numbers (bit for bit), without the 208 bytes per frame those arrays take.
    (Inlined into the kernel: as a called function it was 4-8% slower; inlined, 1-4% slower than the
    single kernel it was split from, measured at 27,000 frames.)"""
    disp, offset, cov_scale, cov_sd = fr.disp, fr.offset, fr.cov_scale, fr.cov_sd
    sight_start, used, mahal2, innov = si.sight_start, si.used, out.mahal2, out.innov
    mu_alpha, cov_alpha, cos_th, sin_th = out.mu_alpha, out.cov_alpha, out.cos_th, out.sin_th
    info_delta, vec_delta = out.info_delta, out.vec_delta
    store = innov.shape[0] == mahal2.shape[0]
    keep = mu_alpha.shape[0] > 1  # per-pose beliefs and per-frame information wanted (not a forward pass alone)
    iva = 1.0 / si.var_b
    var_s, var_b, use_gate, gate = si.var_s, si.var_b, si.use_gate, si.gate
    sight_xy, sight_value, basis, coef = si.xy, si.value, si.basis, si.coef
    size_scale, size_offset, size_var_factor = si.size_scale, si.size_offset, si.size_var_factor
    bearing_offset, bearing_var_factor = si.bearing_offset, si.bearing_var_factor
    mu = _ld3(fr.init_mean, k)
    P = _sym(_ld33(fr.init_cov, k))
    if keep:
        _st3(mu_alpha, ps, mu)
        _st33(cov_alpha, ps, P)
    if not (_fin3(mu) and _fin33(P)):
        return _BAD_FORWARD, 0, loglik
    for j in range(n):
        i = f0 + j
        ux = disp[i, 0]
        uy = disp[i, 1]
        c, s = _cos_sin(mu[2])
        if keep:
            cos_th[ps + j] = c  # for the backward pass
            sin_th[ps + j] = s
        fa = -s * ux - c * uy  # F[0,2]
        fb = c * ux - s * uy  # F[1,2]
        mu = (mu[0] + c * ux - s * uy + offset[i, 0], mu[1] + s * ux + c * uy + offset[i, 1],
              mu[2] + disp[i, 2] + offset[i, 2])  # fmt: skip
        P = _add(_fpft_sym(P, fa, fb), _rot_sym(c, s, _dscale_sym(cov_scale[i], cov_sd[i], sig)))  # P- = F P F^T + Q
        for q in range(sight_start[i], sight_start[i + 1]):
            mahal2[q] = np.nan
            if store:
                innov[q, :] = np.nan
            if not used[q]:
                continue
            var_h = var_s * size_var_factor[q]
            vb = var_b * bearing_var_factor[q]
            fd, bear, e0, e1, t0, t1 = _observe_h(mu, sight_xy[q, 0], sight_xy[q, 1], basis, coef,
                                                  size_scale[q], size_offset[q], bearing_offset[q])  # fmt: skip
            v0 = sight_value[q, 0] - fd
            v1 = _wrap(sight_value[q, 1] - bear)
            # P- H^T columns ph0 = P- h0, ph1 = P- h1; S = H P- H^T + R_obs
            ph0 = (P[0] * e0 + P[1] * e1, P[3] * e0 + P[4] * e1, P[6] * e0 + P[7] * e1)
            ph1 = (P[0] * t0 + P[1] * t1 - P[2], P[3] * t0 + P[4] * t1 - P[5], P[6] * t0 + P[7] * t1 - P[8])
            s00 = e0 * ph0[0] + e1 * ph0[1] + var_h
            s11 = t0 * ph1[0] + t1 * ph1[1] - ph1[2] + vb
            s01 = 0.5 * ((e0 * ph1[0] + e1 * ph1[1]) + (t0 * ph0[0] + t1 * ph0[1] - ph0[2]))
            det_s = s00 * s11 - s01 * s01
            rdet = 1.0 / det_s
            i00 = s11 * rdet
            i11 = s00 * rdet
            i01 = -s01 * rdet
            m2v = v0 * (i00 * v0 + i01 * v1) + v1 * (i01 * v0 + i11 * v1)
            mahal2[q] = m2v
            if not (math.isfinite(m2v) and det_s > 0.0 and s00 > 0.0):
                return _BAD_FORWARD, j, loglik
            if use_gate and m2v > gate:
                continue
            loglik += -0.5 * (m2v + math.log(det_s) + 2.0 * _LOG_2PI)
            if store:
                innov[q, 0], innov[q, 1], innov[q, 2], innov[q, 3], innov[q, 4] = v0, v1, s00, s01, s11
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
            g1 = (vb * k1[0] - xh1[0], vb * k1[1] - xh1[1], vb * k1[2] - xh1[2])
            P = _symm(X[0] + g0[0] * k0[0] + g1[0] * k1[0], X[1] + g0[0] * k0[1] + g1[0] * k1[1],
                      X[2] + g0[0] * k0[2] + g1[0] * k1[2], X[4] + g0[1] * k0[1] + g1[1] * k1[1],
                      X[5] + g0[1] * k0[2] + g1[1] * k1[2], X[8] + g0[2] * k0[2] + g1[2] * k1[2])  # fmt: skip
        if not (_fin3(mu) and _fin33(P)):
            return _BAD_FORWARD, j, loglik
        if not keep:
            continue
        _st3(mu_alpha, i + k + 1, mu)
        _st33(cov_alpha, i + k + 1, P)
        # backward observation information of the frame's applied sightings, h linearized at
        # mu_alpha[i + 1] = mu: sum of H^T R_obs^-1 H and H^T R_obs^-1 (v + H mu), parked in the
        # delta slots of frame i (written out here: as a function of (si, out), even inlined, it made
        # the forward pass 1.5x slower, measured)
        n_app = 0
        for q in range(sight_start[i], sight_start[i + 1]):
            if not used[q] or (use_gate and mahal2[q] > gate):
                continue
            ivh = 1.0 / (var_s * size_var_factor[q])
            ivb = iva / bearing_var_factor[q]
            fd, bear, e0, e1, t0, t1 = _observe_h(mu, sight_xy[q, 0], sight_xy[q, 1], basis, coef,
                                                  size_scale[q], size_offset[q], bearing_offset[q])  # fmt: skip
            z0 = (sight_value[q, 0] - fd + (e0 * mu[0] + e1 * mu[1])) * ivh
            z1 = (_wrap(sight_value[q, 1] - bear) + (t0 * mu[0] + t1 * mu[1] - mu[2])) * ivb
            dY = _symm(ivh * e0 * e0 + ivb * t0 * t0, ivh * e0 * e1 + ivb * t0 * t1, -ivb * t0,
                       ivh * e1 * e1 + ivb * t1 * t1, -ivb * t1, ivb)  # fmt: skip
            dy = (e0 * z0 + t0 * z1, e1 * z0 + t1 * z1, -z1)
            if n_app > 0:
                Yo = _ld33(info_delta, i)
                dY = _symm(Yo[0] + dY[0], Yo[1] + dY[1], Yo[2] + dY[2], Yo[4] + dY[4], Yo[5] + dY[5], Yo[8] + dY[8])
                dy = (vec_delta[i, 0] + dy[0], vec_delta[i, 1] + dy[1], vec_delta[i, 2] + dy[2])
            _st33(info_delta, i, dY)
            _st3(vec_delta, i, dy)
            n_app += 1
        if n_app == 0:
            _st33(info_delta, i, _ZERO33)
            _st3(vec_delta, i, _ZERO3)
    return _OK, -1, loglik


@njit(cache=True, error_model="numpy", fastmath=_FMA, inline="never")
def _backward_log(f0, ps, n, fr, sig, out):
    """Backward information filter + combination of one log (frames f0 .. f0+n-1, poses ps .. ps+n).
    out.info_delta / out.vec_delta hold the observation information parked by the forward pass; they are
    overwritten with Y_delta, y_delta. Returns (status, frame index within the log).
    (A separate, never-inlined function, so that its FMA contractions do not depend on the forward
    pass; rounding-level differences from the reference only.)"""
    disp, offset, cov_scale, cov_sd = fr.disp, fr.offset, fr.cov_scale, fr.cov_sd
    mu_alpha, cov_alpha, mu_gamma, cov_gamma = out.mu_alpha, out.cov_alpha, out.mu_gamma, out.cov_gamma
    info_delta, vec_delta, cos_th, sin_th = out.info_delta, out.vec_delta, out.cos_th, out.sin_th
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
            return _BAD_GAMMA, j
        # observation update at the end pose (the information parked by the forward pass)
        dY = _ld33(info_delta, i)
        dy = _ld3(vec_delta, i)
        Y = _symm(Y[0] + dY[0], Y[1] + dY[1], Y[2] + dY[2], Y[4] + dY[4], Y[5] + dY[5], Y[8] + dY[8])
        y = (y[0] + dy[0], y[1] + dy[1], y[2] + dy[2])
        _st3(vec_delta, i, y)
        _st33(info_delta, i, Y)
        # time update to pose p, g linearized at mu_alpha[p] (cos/sin kept by the forward pass):
        # c = g - F mu = (F[1,2] - F[0,2] th + offset_x, -F[0,2] - F[1,2] th + offset_y, ut + offset_t)
        ux = disp[i, 0]
        uy = disp[i, 1]
        c = cos_th[p]
        s = sin_th[p]
        fa = -s * ux - c * uy
        fb = c * ux - s * uy
        th = mu_alpha[p, 2]
        cv = (fb - fa * th + offset[i, 0], -fa - fb * th + offset[i, 1], disp[i, 2] + offset[i, 2])
        B = _inv_i_plus(_mm(Y, _rot_sym(c, s, _dscale_sym(cov_scale[i], cov_sd[i], sig))))  # (I + Y_delta Q)^-1
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
            return _BAD_BACKWARD, j
    mg, cg = _combine_fast(_ld3(mu_alpha, ps), _ld33(cov_alpha, ps), Y, y)
    _st3(mu_gamma, ps, mg)
    _st33(cov_gamma, ps, cg)
    if not (_fin3(mg) and _fin33(cg)):
        return _BAD_GAMMA, 0
    return _OK, -1


@njit(cache=True, error_model="numpy", fastmath=_FMA)
def _smooth_kernel(fr, si, out, forward_only):
    """The E-step on every log: forward EKF (``_forward_log``), then, unless ``forward_only``, the backward
    information filter and the combination (``_backward_log``; gamma and the deltas are unset otherwise).
    fr: FrameInputs, si: SightingInputs, out: SmoothOutputs. Returns (status, log index, frame index
    within the log, loglik)."""
    sig = _sym(_ld33(fr.sig_a.reshape(1, 3, 3), 0))
    loglik = 0.0
    for k in range(fr.frame_start.shape[0] - 1):
        f0 = fr.frame_start[k]
        n = fr.frame_start[k + 1] - f0
        ps = f0 + k  # pose_start[k]
        status, j, loglik = _forward_log(k, f0, ps, n, fr, si, sig, out, loglik)
        if status != _OK:
            return status, k, j, loglik
        if forward_only:
            continue
        status, j = _backward_log(f0, ps, n, fr, sig, out)
        if status != _OK:
            return status, k, j, loglik
    return _OK, -1, -1, loglik


_NO_INNOV = np.empty((0, 5))


def smooth_compiled(lo: Lowered, batch: Batch, gate: float | None = None, out: Posterior | None = None) -> Posterior:
    """Compiled E-step: forward EKF, backward information filter, combination (docs/em-math.md).

    Same contract as ``learners.inference.reference.smooth``. ``out``: a Posterior of the same batch
    whose arrays are overwritten and returned (the caller must no longer need it). ``gate``: a used
    sighting whose mahal2 exceeds it is not applied (no update, no likelihood term, skipped by the
    backward pass); its mahal2 is still stored so the caller can prune it (``used & (mahal2 > gate)``).
    With extra states (``lo.extra``) the augmented kernel runs instead (``kernels.augmented``).
    """
    if lo.extra is not None:
        return smooth_augmented_compiled(lo, batch, gate)
    frames, sightings = kernel_inputs(lo, batch, gate)
    n, n_s = batch.n_frames, batch.n_sightings
    n_poses = n + batch.n_logs
    if out is not None and out.mu_alpha.shape == (n_poses, 3) and out.mahal2.shape == (n_s,) \
            and out.info_delta.shape == (n, 3, 3):
        # reuse the previous posterior's arrays: fresh 8 MB per call cost ~40% of the time (page faults)
        arrays = (out.mu_alpha, out.cov_alpha, out.mu_gamma, out.cov_gamma, out.info_delta, out.vec_delta, out.mahal2)
    else:
        arrays = (np.empty((n_poses, 3)), np.empty((n_poses, 3, 3)), np.empty((n_poses, 3)), np.empty((n_poses, 3, 3)),
                  np.empty((n, 3, 3)), np.empty((n, 3)), np.empty(n_s))
    # cos/sin of the forward headings, reused by the backward pass (per-thread, reused across calls)
    res = SmoothOutputs(*arrays, innov=_NO_INNOV, cos_th=_scratch("estep_cos", (n_poses,)),
                        sin_th=_scratch("estep_sin", (n_poses,)))
    status, k, j, loglik = _smooth_kernel(frames, sightings, res, False)
    _raise(status, k, j, batch)
    if not math.isfinite(loglik):
        raise FloatingPointError("non-finite log-likelihood in the E-step")
    return Posterior(*arrays[:6], float(loglik), res.mahal2)


def innovations_compiled(lo: Lowered, batch: Batch, out: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """The forward EKF alone (no gate): (loglik, (S, 5) [v_size, v_bearing (rad, wrapped), S00, S01, S11])
    of every applied sighting (NaN rows for the others): the Gaussian innovations the likelihood is
    made of, in the size unit (px or mm) and rad. ``out``: an (S, 5) array to fill and return."""
    if lo.extra is not None:
        return innovations_augmented_compiled(lo, batch, out)
    frames, sightings = kernel_inputs(lo, batch, None)
    n_s = batch.n_sightings
    innov = out if out is not None and out.shape == (n_s, 5) else np.empty((n_s, 5))
    # one-row placeholders: the kernel stores nothing per pose or frame (``_forward_log``); was 208 bytes per
    # frame of scratch (1,000,000 frames: 208 MB) kept for the process's life
    one3, one33 = _scratch("innov_one3", (1, 3)), _scratch("innov_one33", (1, 3, 3))
    res = SmoothOutputs(one3, one33, one3, one33, one33, one3, _scratch("innov_m2", (n_s,)), innov,
                        _scratch("innov_one", (1,)), _scratch("innov_one", (1,)))
    status, k, j, loglik = _smooth_kernel(frames, sightings, res, True)
    _raise(status, k, j, batch)
    if not math.isfinite(loglik):
        raise FloatingPointError("non-finite log-likelihood in the forward filter")
    return float(loglik), innov
