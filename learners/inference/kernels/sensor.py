"""Compiled (numba) sensor curve fit: the ``_sensor_*`` kernels and ``sensor_update_compiled``, twin of
``sensor_stats.update_sensor_curve``; docs/em-math.md is the specification. Units: distances mm,
sizes px or mm, bearings rad; x = d or 1/d per the curve's basis."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from learners.arrays.batch import Batch
from learners.arrays.lowered import BASIS_INVERSE, BASIS_POWER, Lowered
from learners.arrays.posterior import Posterior
from learners.inference.kernels.algebra import _TWO_PI, _f64, _scratch
from learners.inference.kernels.fasttrig import _atan2

# Pass 1 over the used sightings (Cholesky of Sigma_gamma, the 6 cubature points or mu + L z for the
# given normals z, their distances (kept), the bearing residuals' sum of squares, min/max of the
# smoothed-mean distances), then x = d or 1/d and its min/max; pass 2: the normal equations of the
# weighted fit in the Chebyshev basis of u = (2x - (lo + hi)) / (hi - lo) (as
# ``learners.arrays.lowered.fit_polynomial``), each point weighted by size_var_factor^-1 and its column by
# size_scale; the (degree+1)-square solve and the conversion to powers of x are NumPy's; pass 3: the
# sum of squared normalized size residuals (Horner, as polyval).


@njit(cache=True, error_model="numpy")
def _wrap_fast(a):
    """wrap(a) for a SQUARED residual: multiplies by 1/(2 pi) instead of dividing, so it may
    return -pi for pi (same square); otherwise equal to ``_wrap`` up to rounding."""
    return a - _TWO_PI * math.ceil((a - math.pi) * (1.0 / _TWO_PI))


@njit(cache=True, nogil=True, error_model="numpy")
def _sensor_points_xy(sight_idx, pose_idx, mu_gamma, cov_gamma, beacon_xy, obs, bearing_offset, z, cubature, dxs, dys,
                      pto, out):  # fmt: skip
    """Pass 1a, per used sighting n (sighting sight_idx[n] of pose pose_idx[n]): L = Cholesky(Sigma_gamma)
    and the points (6 cubature points mu + sqrt(3) L e_0, e_1, e_2, mu - sqrt(3) L e_0, e_1, e_2, or
    mu + L z[n, s]); for each point the landmark offset (dxs, dys) and heading + o2 - bearing_offset
    (pto), all (n, k).
    out[3:5] = (min, max) distance at the smoothed means; out[5] = 1 if a height obs is not finite.
    Returns -1, else the row whose Sigma_gamma is not positive definite."""
    r3 = math.sqrt(3.0)
    n_pts = dxs.shape[1]
    mlo = np.inf
    mhi = -np.inf
    bad = False
    for n in range(sight_idx.shape[0]):
        i = sight_idx[n]
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
        o2 = obs[i, 1] - bearing_offset[i]
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


@njit(cache=True, nogil=True, error_model="numpy")
def _sensor_dist_resid(dxs, dys, pto, dist, ra2):
    """Pass 1b (branch-free, vectorizes): distance and squared wrapped angle residual
    wrap(bearing - o2)^2 of every point (flat arrays)."""
    for m in range(dxs.shape[0]):
        dx = dxs[m]
        dy = dys[m]
        dist[m] = math.sqrt(dx * dx + dy * dy)
        r = _wrap_fast(_atan2(dy, dx) - pto[m])
        ra2[m] = r * r


@njit(cache=True, nogil=True, error_model="numpy")
def _sensor_reduce(dist, ra2, out):
    """Pass 1c: out[0] = sum ra2, out[1:3] = (min, max) of x (the distance or its inverse);
    out[5] = 1 if one is not finite."""
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


@njit(cache=True, nogil=True)
def _sensor_gram(dist, ws2, wsh, lo, hi, gram, rhs):
    """gram = sum_points ws2 T(u) T(u)^T, rhs = sum_points T(u) wsh, T = Chebyshev polynomials
    T_0..T_deg of u (from dist = x) by chebvander's recurrence; per used sighting n,
    ws2[n] = size_scale^2 / size_var_factor and wsh[n] = size_scale (size - size_offset) / size_var_factor
    (the points' equal weights are the caller's)."""
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
            h = wsh[n]
            w = ws2[n]
            for jj in range(dist.shape[1]):
                u = (2.0 * dist[n, jj] - off) / span
                x2 = 2.0 * u
                t2 = u * x2 - 1.0
                t3 = t2 * x2 - u
                g00 += w
                g01 += w * u
                g02 += w * t2
                g03 += w * t3
                g11 += w * (u * u)
                g12 += w * (u * t2)
                g13 += w * (u * t3)
                g22 += w * (t2 * t2)
                g23 += w * (t2 * t3)
                g33 += w * (t3 * t3)
                r0 += h
                r1 += u * h
                r2 += t2 * h
                r3 += t3 * h
        gram[0, 0], gram[0, 1], gram[0, 2], gram[0, 3] = g00, g01, g02, g03
        gram[1, 1], gram[1, 2], gram[1, 3] = g11, g12, g13
        gram[2, 2], gram[2, 3], gram[3, 3] = g22, g23, g33
        rhs[0], rhs[1], rhs[2], rhs[3] = r0, r1, r2, r3
        m = 0  # skip the generic loop
    elif m == 3:  # the default inverse basis' quadratic (c0 + c1/d + c2/d^2), unrolled: the same operations
        g00 = g01 = g02 = g11 = g12 = g22 = 0.0
        r0 = r1 = r2 = 0.0
        for n in range(dist.shape[0]):
            h = wsh[n]
            w = ws2[n]
            for jj in range(dist.shape[1]):
                u = (2.0 * dist[n, jj] - off) / span
                t2 = u * (2.0 * u) - 1.0
                g00 += w
                g01 += w * u
                g02 += w * t2
                g11 += w * (u * u)
                g12 += w * (u * t2)
                g22 += w * (t2 * t2)
                r0 += h
                r1 += u * h
                r2 += t2 * h
        gram[0, 0], gram[0, 1], gram[0, 2] = g00, g01, g02
        gram[1, 1], gram[1, 2], gram[2, 2] = g11, g12, g22
        rhs[0], rhs[1], rhs[2] = r0, r1, r2
        m = 0  # skip the generic loop
    for n in range(dist.shape[0] if m else 0):
        h = wsh[n]
        w = ws2[n]
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
                    gram[a, b] += w * (ta * T[b])
    m = gram.shape[0]
    for a in range(m):
        for b in range(a):
            gram[a, b] = gram[b, a]


@njit(cache=True, nogil=True)
def _sensor_height_ss(sight_idx, obs, dist, coef, size_scale, size_offset, size_var_factor):
    """sum over points of (size_scale f(x) + size_offset - size)^2 / size_var_factor, f by Horner in
    ascending powers of x = dist (as polyval)."""
    nc = coef.shape[0]
    ss = 0.0
    for n in range(dist.shape[0]):
        i = sight_idx[n]
        h = obs[i, 0]
        sc = size_scale[i]
        so = size_offset[i]
        iv = 1.0 / size_var_factor[i]
        for jj in range(dist.shape[1]):
            d = dist[n, jj]
            f = coef[nc - 1]
            for t in range(nc - 2, -1, -1):
                f = coef[t] + f * d
            r = (sc * f + so) - h
            ss += r * r * iv
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


def sensor_update_compiled(lo: Lowered, batch: Batch, post: Posterior, rng: np.random.Generator,
                           method: str = "sample", n_samples: int = 1, degree: int = 3):
    """Compiled twin of ``sensor_stats.update_sensor_curve`` (with ``sensor_points``): returns
    (coef (degree+1,) in ``lo.basis``, sigma_size, sigma_bearing, (min, max) distance (mm) at the
    smoothed means).

    ``sample`` draws ``rng.standard_normal((n_used, n_samples, 3))`` exactly as the reference does
    (the generator is left where the reference leaves it, also when the Cholesky fails)."""
    sights = np.flatnonzero(np.asarray(batch.used, bool))
    poses = batch.sight_pose[sights]
    n = sights.size
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
    if lo.basis not in (BASIS_POWER, BASIS_INVERSE):
        raise ValueError(f"unknown sensor basis {lo.basis}")
    n_s = batch.n_sightings
    obs = _f64(batch.sight_value, (n_s, 2))
    dxs = _scratch("dxs", (n, k))
    dys = _scratch("dys", (n, k))
    pto = _scratch("pto", (n, k))
    out = np.zeros(6)
    bad = _sensor_points_xy(sights, poses, _f64(post.mu_gamma), _f64(post.cov_gamma), _f64(batch.sight_xy, (n_s, 2)),
                            obs, _f64(lo.bearing_offset, (n_s,)), z, cub, dxs, dys, pto, out)  # fmt: skip
    if bad >= 0:
        if not cub:
            rng.bit_generator.state = state  # the reference fails before drawing
        raise FloatingPointError(f"sensor M-step: smoothed covariance not positive definite "
                                 f"(sighting {int(sights[bad])})")  # fmt: skip
    dist = _scratch("dist", (n, k))
    ra2 = _scratch("ra2", (n * k,))
    _sensor_dist_resid(dxs.reshape(-1), dys.reshape(-1), pto.reshape(-1), dist.reshape(-1), ra2)
    bvf = _f64(lo.bearing_var_factor, (n_s,))[sights]
    if np.any(bvf != 1.0):
        ra2.reshape(n, k)[:] /= bvf[:, None]  # the bearing residuals weighted as the size ones
    if lo.basis == BASIS_INVERSE:
        np.divide(1.0, dist, out=dist)  # x = 1/d
    _sensor_reduce(dist.reshape(-1), ra2, out)
    m = n * k
    if m < degree + 1:
        raise ValueError(f"need at least {degree + 1} points to fit a degree-{degree} polynomial, got {m}")
    if out[5] != 0.0:
        raise FloatingPointError("fit_polynomial: non-finite input")
    x_lo, x_hi = float(out[1]), float(out[2])
    if x_hi <= x_lo:
        raise ValueError(f"need at least two distinct distances to fit a polynomial, got all {x_lo}")
    sc = _f64(lo.size_scale, (n_s,))
    so = _f64(lo.size_offset, (n_s,))
    vf = _f64(lo.size_var_factor, (n_s,))
    iv = 1.0 / vf[sights]
    ws2 = sc[sights] * sc[sights] * iv
    wsh = sc[sights] * (obs[sights, 0] - so[sights]) * iv
    w = 1.0 / k
    gram = np.empty((degree + 1, degree + 1))
    rhs = np.empty(degree + 1)
    _sensor_gram(dist, ws2, wsh, x_lo, x_hi, gram, rhs)
    cheb = np.linalg.solve(gram * w, rhs * w)
    conv = _cheb_to_power(cheb, x_lo, x_hi)
    coef = np.zeros(degree + 1)
    coef[: len(conv)] = conv
    wsum = m * w
    sigma_s = math.sqrt(_sensor_height_ss(sights, obs, dist, coef, sc, so, vf) * w / wsum)
    sigma_b = math.sqrt(out[0] * w / wsum)
    return coef, sigma_s, sigma_b, (float(out[3]), float(out[4]))
