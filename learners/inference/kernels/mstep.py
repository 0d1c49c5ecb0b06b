"""Compiled (numba) M-step: the fused action update (``_action_update_kernel``,
``action_update_compiled``) and the fused sensor update (``_sensor_*`` kernels,
``sensor_update_compiled``). Twins of ``action_mstep.update_action_model`` /
``sensor_mstep.update_sensor_model``; docs/em-math.md is the specification."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from learners.em.data import Batch
from learners.em.kernels.algebra import (
    _BAD_ACTION, _OK, _TWO_PI, _ZERO33, _add, _f64, _fin3, _fin33, _fpft, _inv, _inv_i_plus, _ld3, _ld33, _mm,
    _mv, _raise, _scratch, _st3, _st33, _sym,
)
from learners.inference.kernels.fasttrig import _atan2, _cos_sin_all
from learners.em.params import Params
from learners.em.posterior import Posterior


# ----------------------------------------------------------------------------------------------
# fused M-step kernels (used by fit.m_step on the compiled path)
# ----------------------------------------------------------------------------------------------
#
# Action update: the mu*_i, C*_i of ``action_mstep.action_statistics``, rearranged so that each frame needs
# ONE 3x3 inverse and C*_i is never stored. With B = (I + Y'P1)^-1, Y_d = B Y', y_d = B (y' + Y' m1):
#     I + Y_d Sigma = B (I + Y' (P1 + Sigma))  =>  with K = (I + Y' (P1 + Sigma))^-1:
#     C*_i = (Sigma^-1 + Y_d)^-1 = Sigma (I + Y_d Sigma)^-1 = Sigma K (I + Y' P1),
#     mu*_i = mu_hat + C*_i B (y' + Y' (m1 - mu_hat)) = mu_hat + Sigma K (y' + Y' (m1 - mu_hat)).
# Sigma is shared by all frames, so sum_i C*_i = Sigma sum_i K_i (I + Y'_i P1_i): one 3x3 sum.
# Pass 1 (per frame): mu*_i (kept, (N, 3)), per-action sums and counts, sum_i K_i (I + Y'_i P1_i);
# pass 2 (only with learn_noise): sum_i r_i r_i^T, r_i = mu*_i - disp_new[a_i].


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


@njit(cache=True, error_model="numpy")
def _action_update_kernel(actions, frame_start, disp, sig_a, mu_alpha, cov_alpha, mu_gamma, info_delta, vec_delta,
                          learn_noise, mu_star, new_disp, cov_out, cos_th, sin_th):  # fmt: skip
    """Fills mu_star (N, 3), new_disp (n_act, 3) and (if learn_noise) cov_out (3, 3) = Sigma_new.
    Returns (status, log index, frame index within the log).

    Evaluated in the world frame: with R = R3(theta_p) = L2^T and J = L2^T L1 = -(I with
    J[0,2] = -dy, J[1,2] = dx) (dx, dy = smoothed end minus start position),
    K = L2 Kw L2^T, Kw = (I + Y_delta (J P_alpha J^T + R Sigma R^T))^-1, and
    mu*_i = mu_hat + Sigma L2 Kw (y_delta + Y_delta (J (mu_alpha - g0) - g0 - R mu_hat)),
    C*_i = Sigma L2 Kw (I + Y_delta J P_alpha J^T) L2^T.
    """
    Sig = _ld33(sig_a.reshape(1, 3, 3), 0)
    _, det = _inv(Sig)
    if not (math.isfinite(det) and det != 0.0):  # the reference inverts Sigma: singular is an error
        return _BAD_ACTION, -1, -1
    n_act = disp.shape[0]
    sums = np.zeros((n_act, 3))
    counts = np.zeros(n_act, np.int64)
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
            dx = mu_gamma[p + 1, 0] - g0[0]
            dy = mu_gamma[p + 1, 1] - g0[1]
            a = actions[i]
            mh = (disp[a, 0], disp[a, 1], disp[a, 2])
            P1w = _fpft(_ld33(cov_alpha, p), -dy, dx)  # J P_alpha J^T
            Mw = _add(P1w, _rot_sandwich(c, s, Sig))
            Y = _ld33(info_delta, i)
            Kw = _inv_i_plus(_mm(Y, Mw))
            # w = J (mu_alpha - g0) - g0 - R mu_hat
            e0 = mu_alpha[p, 0] - g0[0]
            e1 = mu_alpha[p, 1] - g0[1]
            e2 = mu_alpha[p, 2] - g0[2]
            w = (-e0 + dy * e2 - g0[0] - (c * mh[0] - s * mh[1]),
                 -e1 - dx * e2 - g0[1] - (s * mh[0] + c * mh[1]),
                 -e2 - g0[2] - mh[2])  # fmt: skip
            Yw = _mv(Y, w)
            v = _mv(Kw, (vec_delta[i, 0] + Yw[0], vec_delta[i, 1] + Yw[1], vec_delta[i, 2] + Yw[2]))
            v = (c * v[0] + s * v[1], -s * v[0] + c * v[1], v[2])  # L2 v
            q = _mv(Sig, v)
            ms = (mh[0] + q[0], mh[1] + q[1], mh[2] + q[2])
            _st3(mu_star, i, ms)
            sums[a, 0] += ms[0]
            sums[a, 1] += ms[1]
            sums[a, 2] += ms[2]
            counts[a] += 1
            if not (_fin3(ms) and _fin33(Kw)):
                return _BAD_ACTION, k, j
            if learn_noise:
                YP = _mm(Y, P1w)
                Aw = _mm(Kw, (1.0 + YP[0], YP[1], YP[2], YP[3], 1.0 + YP[4], YP[5], YP[6], YP[7], 1.0 + YP[8]))
                Asum = _add(Asum, _rot_sandwich(c, -s, Aw))  # L2 Aw L2^T
    for a in range(n_act):
        if counts[a] > 0:
            for t in range(3):
                new_disp[a, t] = sums[a, t] / counts[a]
        else:
            for t in range(3):
                new_disp[a, t] = disp[a, t]
    n = mu_star.shape[0]
    if learn_noise and n > 0:
        r00 = r01 = r02 = r11 = r12 = r22 = 0.0
        for i in range(n):
            a = actions[i]
            r0 = mu_star[i, 0] - new_disp[a, 0]
            r1 = mu_star[i, 1] - new_disp[a, 1]
            r2 = mu_star[i, 2] - new_disp[a, 2]
            r00 += r0 * r0
            r01 += r0 * r1
            r02 += r0 * r2
            r11 += r1 * r1
            r12 += r1 * r2
            r22 += r2 * r2
        R = (r00, r01, r02, r01, r11, r12, r02, r12, r22)
        C = _mm(Sig, Asum)
        inv_n = 1.0 / n
        out = _sym((C[0] * inv_n + R[0] * inv_n, C[1] * inv_n + R[1] * inv_n, C[2] * inv_n + R[2] * inv_n,
                    C[3] * inv_n + R[3] * inv_n, C[4] * inv_n + R[4] * inv_n, C[5] * inv_n + R[5] * inv_n,
                    C[6] * inv_n + R[6] * inv_n, C[7] * inv_n + R[7] * inv_n, C[8] * inv_n + R[8] * inv_n))  # fmt: skip
        _st33(cov_out.reshape(1, 3, 3), 0, out)
        if not _fin33(out):
            return _BAD_ACTION, -1, -1
    return _OK, -1, -1


def action_update_compiled(params: Params, batch: Batch, post: Posterior, learn_noise: bool = False):
    """Compiled twin of ``action_mstep.update_action_model`` (with ``action_statistics``):
    returns the new (disp (n_act, 3), cov (3, 3)) without forming the (N, 3, 3) C*_i.
    Actions never executed keep their previous displacement; Sigma_A is kept unless ``learn_noise``."""
    n = batch.n_frames
    actions = np.ascontiguousarray(batch.actions, dtype=np.int64)
    disp = _f64(params.action.disp)
    if n and (actions.min() < 0 or actions.max() >= disp.shape[0]):
        raise ValueError("action index out of range")
    sig_a = _f64(params.action.cov, (3, 3))
    mu_star = _scratch("mu_star", (n, 3))
    new_disp = np.empty_like(disp)
    cov = sig_a.copy()
    mu_gamma = _f64(post.mu_gamma)
    cos_th = _scratch("cos_th", (mu_gamma.shape[0],))
    sin_th = _scratch("sin_th", (mu_gamma.shape[0],))
    _cos_sin_all(mu_gamma[:, 2], cos_th, sin_th)  # strided view: no copy
    status, k, j = _action_update_kernel(
        actions, np.ascontiguousarray(batch.frame_start, dtype=np.int64), disp, sig_a,
        _f64(post.mu_alpha), _f64(post.cov_alpha), mu_gamma, _f64(post.info_delta),
        _f64(post.vec_delta), bool(learn_noise), mu_star, new_disp, cov, cos_th, sin_th,
    )  # fmt: skip
    _raise(status, k, j, batch)
    return new_disp, cov


# Sensor update: pass 1 over the used sightings (Cholesky of Sigma_gamma, the 6 cubature points or
# mu + L z for the given normals z, their distances (kept), the angle residuals' weighted sum of
# squares, min/max of the point distances and of the smoothed-mean distances); pass 2: the normal
# equations of the weighted fit in the Chebyshev basis of u = (2d - (lo + hi)) / (hi - lo) (as
# ``sensor_mstep.fit_polynomial``); the (degree+1)-square solve and the conversion to powers of d
# are NumPy's; pass 3: the weighted sum of squared height residuals (Horner, as polyval).


@njit(cache=True, error_model="numpy")
def _wrap_fast(a):
    """wrap(a) for a SQUARED residual: multiplies by 1/(2 pi) instead of dividing, so it may
    return -pi for pi (same square); otherwise equal to ``_wrap`` up to rounding."""
    return a - _TWO_PI * math.ceil((a - math.pi) * (1.0 / _TWO_PI))


@njit(cache=True, error_model="numpy")
def _sensor_points_xy(frame_idx, pose_idx, mu_gamma, cov_gamma, beacon_xy, obs, z, cubature, dxs, dys, pto, out):
    """Pass 1a, per used sighting: L = Cholesky(Sigma_gamma) and the points (6 cubature points
    mu + sqrt(3) L e_0, e_1, e_2, mu - sqrt(3) L e_0, e_1, e_2, or mu + L z[n, s]); for each point
    the beacon offset (dxs, dys) and heading + o2 (pto), all (n, k).
    out[3:5] = (min, max) distance at the smoothed means; out[5] = 1 if a height obs is not finite.
    Returns -1, else the row whose Sigma_gamma is not positive definite."""
    r3 = math.sqrt(3.0)
    n_pts = dxs.shape[1]
    mlo = np.inf
    mhi = -np.inf
    bad = False
    for n in range(frame_idx.shape[0]):
        i = frame_idx[n]
        p = pose_idx[n]
        l00 = cov_gamma[p, 0, 0]
        if not l00 > 0.0:
            return n
        l00 = math.sqrt(l00)
        l10 = cov_gamma[p, 1, 0] / l00
        l20 = cov_gamma[p, 2, 0] / l00
        t = cov_gamma[p, 1, 1] - l10 * l10
        if not t > 0.0:
            return n
        l11 = math.sqrt(t)
        l21 = (cov_gamma[p, 2, 1] - l20 * l10) / l11
        t = cov_gamma[p, 2, 2] - l20 * l20 - l21 * l21
        if not t > 0.0:
            return n
        l22 = math.sqrt(t)
        bx = beacon_xy[i, 0]
        by = beacon_xy[i, 1]
        o2 = obs[i, 1]
        mx = mu_gamma[p, 0]
        my = mu_gamma[p, 1]
        mt = mu_gamma[p, 2]
        dm = math.hypot(bx - mx, by - my)
        mlo = dm if dm < mlo else mlo
        mhi = dm if dm > mhi else mhi
        if not math.isfinite(obs[i, 0]):
            bad = True
        if cubature:
            for jj in range(3):
                if jj == 0:
                    e0, e1, e2 = r3 * l00, r3 * l10, r3 * l20
                elif jj == 1:
                    e0, e1, e2 = 0.0, r3 * l11, r3 * l21
                else:
                    e0, e1, e2 = 0.0, 0.0, r3 * l22
                dxs[n, jj] = bx - (mx + e0)
                dys[n, jj] = by - (my + e1)
                pto[n, jj] = (mt + e2) + o2
                dxs[n, jj + 3] = bx - (mx - e0)
                dys[n, jj + 3] = by - (my - e1)
                pto[n, jj + 3] = (mt - e2) + o2
        else:
            for jj in range(n_pts):
                z0 = z[n, jj, 0]
                z1 = z[n, jj, 1]
                z2 = z[n, jj, 2]
                dxs[n, jj] = bx - (mx + l00 * z0)
                dys[n, jj] = by - (my + (l10 * z0 + l11 * z1))
                pto[n, jj] = (mt + (l20 * z0 + l21 * z1 + l22 * z2)) + o2
    out[3] = mlo
    out[4] = mhi
    out[5] = 1.0 if bad else 0.0
    return -1


@njit(cache=True, error_model="numpy")
def _sensor_dist_resid(dxs, dys, pto, dist, ra2):
    """Pass 1b (branch-free, vectorizes): distance and squared wrapped angle residual
    wrap(bearing - o2)^2 of every point (flat arrays)."""
    for m in range(dxs.shape[0]):
        dx = dxs[m]
        dy = dys[m]
        dist[m] = math.sqrt(dx * dx + dy * dy)
        r = _wrap_fast(_atan2(dy, dx) - pto[m])
        ra2[m] = r * r


@njit(cache=True, error_model="numpy")
def _sensor_reduce(dist, ra2, out):
    """Pass 1c: out[0] = sum ra2, out[1:3] = (min, max) distance; out[5] = 1 if a distance is not finite."""
    sa = 0.0
    lo = np.inf
    hi = -np.inf
    fin = 0.0
    for m in range(dist.shape[0]):
        d = dist[m]
        sa += ra2[m]
        lo = d if d < lo else lo
        hi = d if d > hi else hi
        fin += d - d  # NaN unless every distance is finite
    out[0] = sa
    out[1] = lo
    out[2] = hi
    if fin != 0.0:
        out[5] = 1.0


@njit(cache=True)
def _sensor_gram(frame_idx, obs, dist, lo, hi, gram, rhs):
    """gram = sum_points T(u) T(u)^T, rhs = sum_points T(u) o1 (unweighted: equal weights are the
    caller's), T = Chebyshev polynomials T_0..T_deg by chebvander's recurrence."""
    m = gram.shape[0]
    T = np.empty(m)
    T[0] = 1.0
    off = lo + hi
    span = hi - lo
    for a in range(m):
        rhs[a] = 0.0
        for b in range(m):
            gram[a, b] = 0.0
    if m == 4:  # the paper's cubic, unrolled
        g00 = g01 = g02 = g03 = g11 = g12 = g13 = g22 = g23 = g33 = 0.0
        r0 = r1 = r2 = r3 = 0.0
        for n in range(dist.shape[0]):
            h = obs[frame_idx[n], 0]
            for jj in range(dist.shape[1]):
                u = (2.0 * dist[n, jj] - off) / span
                x2 = 2.0 * u
                t2 = u * x2 - 1.0
                t3 = t2 * x2 - u
                g00 += 1.0
                g01 += u
                g02 += t2
                g03 += t3
                g11 += u * u
                g12 += u * t2
                g13 += u * t3
                g22 += t2 * t2
                g23 += t2 * t3
                g33 += t3 * t3
                r0 += h
                r1 += u * h
                r2 += t2 * h
                r3 += t3 * h
        gram[0, 0], gram[0, 1], gram[0, 2], gram[0, 3] = g00, g01, g02, g03
        gram[1, 1], gram[1, 2], gram[1, 3] = g11, g12, g13
        gram[2, 2], gram[2, 3], gram[3, 3] = g22, g23, g33
        rhs[0], rhs[1], rhs[2], rhs[3] = r0, r1, r2, r3
        m = 0  # skip the generic loop
    for n in range(dist.shape[0] if m else 0):
        h = obs[frame_idx[n], 0]
        for jj in range(dist.shape[1]):
            u = (2.0 * dist[n, jj] - off) / span
            if m > 1:
                T[1] = u
                x2 = 2.0 * u
                for a in range(2, m):
                    T[a] = T[a - 1] * x2 - T[a - 2]
            for a in range(m):
                ta = T[a]
                rhs[a] += ta * h
                for b in range(a, m):
                    gram[a, b] += ta * T[b]
    m = gram.shape[0]
    for a in range(m):
        for b in range(a):
            gram[a, b] = gram[b, a]


@njit(cache=True)
def _sensor_height_ss(frame_idx, obs, dist, coef):
    """sum over points of (f(d) - o1)^2, f by Horner in ascending powers of d (as polyval)."""
    nc = coef.shape[0]
    ss = 0.0
    for n in range(dist.shape[0]):
        h = obs[frame_idx[n], 0]
        for jj in range(dist.shape[1]):
            d = dist[n, jj]
            f = coef[nc - 1]
            for t in range(nc - 2, -1, -1):
                f = coef[t] + f * d
            r = f - h
            ss += r * r
    return ss


def _cheb_to_power(cheb, lo: float, hi: float) -> list[float]:
    """Ascending power coefficients (in d) of the Chebyshev series ``cheb`` on the domain [lo, hi]:
    the same operations as ``np.polynomial.Chebyshev(cheb, domain=[lo, hi]).convert(kind=Polynomial)``
    (Clenshaw's recurrence on degree-1 polynomials; every product has at most two terms, so the
    result is bit-identical) in plain Python floats, ~20x faster for these few coefficients."""

    def add(a, b):
        return [(a[k] if k < len(a) else 0.0) + (b[k] if k < len(b) else 0.0) for k in range(max(len(a), len(b)))]

    def sub(a, b):
        return [(a[k] if k < len(a) else 0.0) - (b[k] if k < len(b) else 0.0) for k in range(max(len(a), len(b)))]

    def mul1(a, y):  # a * (y[0] + y[1] d)
        out = [a[0] * y[0]]
        for k in range(1, len(a)):
            out.append(a[k] * y[0] + a[k - 1] * y[1])
        out.append(a[-1] * y[1])
        return out

    span = hi - lo
    scl = 2.0 / span
    x = (-hi - lo) / span + 0.0 * scl, scl  # the mapped variable u = off + scl d
    c = [float(v) for v in cheb]
    if len(c) == 1:
        return [c[0]]
    if len(c) == 2:
        return add([c[0]], mul1([c[1]], x))
    x2 = (2.0 * x[0], 2.0 * x[1])
    c0, c1 = [c[-2]], [c[-1]]
    for i in range(3, len(c) + 1):
        c0, c1 = sub([c[-i]], c1), add(c0, mul1(c1, x2))
    return add(c0, mul1(c1, x))


def sensor_update_compiled(params: Params, batch: Batch, post: Posterior, rng: np.random.Generator,
                           method: str = "sample", n_samples: int = 1, degree: int = 3):
    """Compiled twin of ``sensor_mstep.update_sensor_model`` (with ``sensor_points``): returns
    (coef (degree+1,), sigma_height, sigma_angle, (min, max) distance at the smoothed means).

    ``sample`` draws ``rng.standard_normal((n_used, n_samples, 3))`` exactly as the reference does
    (the generator is left where the reference leaves it, also when the Cholesky fails)."""
    frames = np.flatnonzero(np.asarray(batch.used, bool))
    poses = batch.frame_to_pose[frames] + 1
    n = frames.size
    if method == "sample":
        if n_samples < 1:
            raise ValueError(f"n_samples must be >= 1, got {n_samples}")
        state = rng.bit_generator.state
        z = rng.standard_normal((n, n_samples, 3))
        k, cub = n_samples, False
    elif method == "cubature":
        z = np.empty((0, 0, 3))
        k, cub = 6, True
    else:
        raise ValueError(f"unknown method {method!r} (use 'sample' or 'cubature')")
    obs = _f64(batch.obs)
    dxs = _scratch("dxs", (n, k))
    dys = _scratch("dys", (n, k))
    pto = _scratch("pto", (n, k))
    out = np.zeros(6)
    bad = _sensor_points_xy(frames, poses, _f64(post.mu_gamma), _f64(post.cov_gamma), _f64(batch.beacon_xy), obs,
                            z, cub, dxs, dys, pto, out)  # fmt: skip
    if bad >= 0:
        if not cub:
            rng.bit_generator.state = state  # the reference fails before drawing
        raise FloatingPointError(f"sensor M-step: smoothed covariance not positive definite "
                                 f"(batch frame {int(frames[bad])})")  # fmt: skip
    dist = _scratch("dist", (n, k))
    ra2 = _scratch("ra2", (n * k,))
    _sensor_dist_resid(dxs.reshape(-1), dys.reshape(-1), pto.reshape(-1), dist.reshape(-1), ra2)
    _sensor_reduce(dist.reshape(-1), ra2, out)
    m = n * k
    if m < degree + 1:
        raise ValueError(f"need at least {degree + 1} points to fit a degree-{degree} polynomial, got {m}")
    if out[5] != 0.0:
        raise FloatingPointError("fit_polynomial: non-finite input")
    lo, hi = float(out[1]), float(out[2])
    if hi <= lo:
        raise ValueError(f"need at least two distinct distances to fit a polynomial, got all {lo} mm")
    w = 1.0 / k
    gram = np.empty((degree + 1, degree + 1))
    rhs = np.empty(degree + 1)
    _sensor_gram(frames, obs, dist, lo, hi, gram, rhs)
    cheb = np.linalg.solve(gram * w, rhs * w)
    conv = _cheb_to_power(cheb, lo, hi)
    coef = np.zeros(degree + 1)
    coef[: len(conv)] = conv
    wsum = m * w
    sigma_h = math.sqrt(_sensor_height_ss(frames, obs, dist, coef) * w / wsum)
    sigma_a = math.sqrt(out[0] * w / wsum)
    return coef, sigma_h, sigma_a, (float(out[3]), float(out[4]))
