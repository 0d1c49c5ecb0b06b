"""Sensor curve fit (paper section III-B; docs/em-math.md "Sensor M-step"), vectorized.

Over the used sightings (of the end pose of their frame, smoothed belief gamma), poses are drawn
from N(mu_gamma, Sigma_gamma) (``method="sample"``, the paper) or taken at the 2n = 6 cubature
points (``method="cubature"``); each point gives a distance d (mm) and a bearing (rad) to the
landmark seen. The lowered sighting model is size = size_scale f(d) + size_offset + e,
var(e) = sigma_size^2 size_var_factor, f(d) = sum_k coef[k] x^k with x = d or 1/d (``lo.basis``):
f is fitted by weighted least squares of (size - size_offset) on size_scale phi_k(x), weights
1/size_var_factor, in a Chebyshev basis of the scaled x; sigma_size^2 and sigma_bearing^2 are
weighted MEANS of squared (normalized) residuals (the paper's formula lacks the 1/N).
"""

from __future__ import annotations

import numpy as np

from aibo_core import geometry
from learners.arrays.batch import Batch
from learners.arrays.lowered import BASIS_INVERSE, BASIS_POWER, Lowered, fit_polynomial
from learners.arrays.posterior import Posterior


def used_sightings(batch: Batch) -> tuple[np.ndarray, np.ndarray]:
    """(indices of the used sightings, index of the pose each is of)."""
    idx = np.flatnonzero(batch.used)
    return idx, batch.sight_pose[idx]


def sensor_points(lo: Lowered, batch: Batch, post: Posterior, rng: np.random.Generator,
                  method: str = "sample", n_samples: int = 1):
    """Weighted points for the sensor regression.

    ``sample``: for each used sighting j (in sighting order) ``n_samples`` poses mu + L z with
    L = cholesky(Sigma_gamma) and z = ``rng.standard_normal((n_used, n_samples, 3))[j, s]``;
    weight 1/n_samples. ``cubature``: mu + sqrt(3) L e_0, e_1, e_2, then mu - sqrt(3) L e_0, e_1, e_2;
    weight 1/6. Points of one sighting are contiguous.

    Returns ``dist`` (M,) mm, ``bearing`` (M,) rad (wrapped, from the heading, plus the sighting's
    bearing_offset), ``sight`` (M,) index of the sighting of each point, ``weight`` (M,).
    """
    idx, pose = used_sightings(batch)
    n = len(idx)
    mu = post.mu_gamma[pose]  # (n, 3)
    try:
        L = np.linalg.cholesky(post.cov_gamma[pose])  # (n, 3, 3)
    except np.linalg.LinAlgError as e:
        raise FloatingPointError(f"sensor M-step: smoothed covariance not positive definite: {e}") from e
    if method == "sample":
        if n_samples < 1:
            raise ValueError(f"n_samples must be >= 1, got {n_samples}")
        z = rng.standard_normal((n, n_samples, 3))
        pts = mu[:, None, :] + np.einsum("nij,nsj->nsi", L, z)
        k = n_samples
    elif method == "cubature":
        s3L = np.sqrt(3.0) * np.swapaxes(L, 1, 2)  # row j = sqrt(3) L e_j
        pts = np.concatenate([mu[:, None, :] + s3L, mu[:, None, :] - s3L], axis=1)  # (n, 6, 3)
        k = 6
    else:
        raise ValueError(f"unknown method {method!r} (use 'sample' or 'cubature')")
    pts = pts.reshape(n * k, 3)
    sight = np.repeat(idx, k)
    dx = batch.sight_xy[sight, 0] - pts[:, 0]
    dy = batch.sight_xy[sight, 1] - pts[:, 1]
    bearing = geometry.wrap(np.arctan2(dy, dx) - pts[:, 2] + lo.bearing_offset[sight])
    return np.hypot(dx, dy), bearing, sight, np.full(n * k, 1.0 / k)


def basis_variable(basis: int, d):
    """x of the curve's basis for distances d (mm): d (power) or 1/d (inverse)."""
    if basis == BASIS_POWER:
        return np.asarray(d, dtype=float)
    if basis == BASIS_INVERSE:
        return 1.0 / np.asarray(d, dtype=float)
    raise ValueError(f"unknown sensor basis {basis}")


def update_sensor_curve(lo: Lowered, batch: Batch, post: Posterior, rng: np.random.Generator,
                        method: str = "sample", n_samples: int = 1, degree: int = 3, held: np.ndarray | None = None):
    """New sensor curve from the used sightings: (coef (degree+1,) in ``lo.basis``, sigma_size,
    sigma_bearing, (dmin, dmax) mm at the smoothed means).

    coef: ``fit_polynomial`` of (size - size_offset) on size_scale phi(x) with weights
    point weight / size_var_factor; sigma_size^2 = weighted mean of
    (size_scale f(x) + size_offset - size)^2 / size_var_factor; sigma_bearing^2 = weighted mean of
    wrap(bearing + bearing_offset - observed bearing)^2 / bearing_var_factor.
    ``held``: the curve is not fitted but kept at these coefficients (``EMOptions.range_curve``), and sigma_size is
    the spread about it (the conditional maximum).
    """
    dist, bearing, sight, w = sensor_points(lo, batch, post, rng, method, n_samples)
    x = basis_variable(lo.basis, dist)
    size = batch.sight_value[sight, 0]
    sc = lo.size_scale[sight]
    off = lo.size_offset[sight]
    vf = lo.size_var_factor[sight]
    coef = fit_polynomial(x, size - off, w / vf, degree, scale=sc) if held is None else np.asarray(held, float)
    wsum = w.sum()
    res_s = sc * np.polynomial.polynomial.polyval(x, coef) + off - size
    res_b = geometry.wrap(bearing - batch.sight_value[sight, 1])
    sigma_s = float(np.sqrt(np.sum(w * res_s**2 / vf) / wsum))
    sigma_b = float(np.sqrt(np.sum(w * res_b**2 / lo.bearing_var_factor[sight]) / wsum))
    idx, pose = used_sightings(batch)
    dm = np.hypot(batch.sight_xy[idx, 0] - post.mu_gamma[pose, 0], batch.sight_xy[idx, 1] - post.mu_gamma[pose, 1])
    return coef, sigma_s, sigma_b, (float(dm.min()), float(dm.max()))
