"""Sensor M-step (paper section III-B; docs/em-math.md "Sensor M-step"), vectorized.

Over the used sightings (end pose p+1 of frame i, smoothed belief gamma), poses are drawn
from N(mu_gamma, Sigma_gamma) (``method="sample"``, the paper) or taken at the 2n = 6
cubature points (``method="cubature"``); each point gives a distance d (mm) and a wrapped
bearing (rad) to the beacon seen. f (px, ascending powers of d in mm) is fitted by weighted
least squares in a scaled variable; sigma_h^2 and sigma_a^2 are weighted MEANS of squared
residuals (the paper's formula lacks the 1/N).
"""

from __future__ import annotations

import numpy as np

from aibo_core import geometry
from .data import Batch
from .params import Params, SensorModel
from .posterior import Posterior


def _used_end_poses(batch: Batch) -> tuple[np.ndarray, np.ndarray]:
    """(frames with a used sighting, index of their END pose)."""
    frames = np.flatnonzero(batch.used)
    return frames, batch.frame_to_pose[frames] + 1


def sensor_points(params: Params, batch: Batch, post: Posterior, rng: np.random.Generator,
                  method: str = "sample", n_samples: int = 1):
    """Weighted points for the sensor regression.

    ``sample``: for each used sighting j (in frame order) ``n_samples`` poses
    mu + L z with L = cholesky(Sigma_gamma) and z = ``rng.standard_normal((n_used, n_samples, 3))[j, s]``;
    weight 1/n_samples. ``cubature``: mu + sqrt(3) L e_0, e_1, e_2, then mu - sqrt(3) L e_0, e_1, e_2;
    weight 1/6. Points of one sighting are contiguous.

    Returns ``dist`` (M,) mm, ``bearing`` (M,) rad (wrapped, from the heading), ``obs`` (M, 2)
    (height px, angle rad) of the sighting, ``weight`` (M,).
    """
    frames, pose = _used_end_poses(batch)
    n = len(frames)
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
    bxy = np.repeat(batch.beacon_xy[frames], k, axis=0)
    h, _, dist = geometry.observe(pts, bxy, params.sensor)
    obs = np.repeat(batch.obs[frames], k, axis=0)
    weight = np.full(n * k, 1.0 / k)
    return dist, h[:, 1], obs, weight


def fit_polynomial(d, h, w, degree: int = 3) -> np.ndarray:
    """Weighted least-squares polynomial f minimizing sum w (f(d) - h)^2.

    Well-conditioned: the fit is done in a Chebyshev basis of the scaled variable
    u = (d - c)/s in [-1, 1] (normal equations of a (degree+1)-square Gram matrix, whose
    condition number stays small in that basis), then converted to ascending powers of d (mm).
    Returns ``degree + 1`` coefficients.
    """
    d = np.asarray(d, dtype=float)
    h = np.asarray(h, dtype=float)
    w = np.asarray(w, dtype=float)
    if len(d) < degree + 1:
        raise ValueError(f"need at least {degree + 1} points to fit a degree-{degree} polynomial, got {len(d)}")
    if not (np.isfinite(d).all() and np.isfinite(h).all() and np.isfinite(w).all()):
        raise FloatingPointError("fit_polynomial: non-finite input")
    lo, hi = float(d.min()), float(d.max())
    if hi <= lo:
        raise ValueError(f"need at least two distinct distances to fit a polynomial, got all {lo} mm")
    V = np.polynomial.chebyshev.chebvander((2.0 * d - (lo + hi)) / (hi - lo), degree)
    Vw = V * w[:, None]
    cheb = np.linalg.solve(Vw.T @ V, Vw.T @ h)
    coef = np.polynomial.Chebyshev(cheb, domain=[lo, hi]).convert(kind=np.polynomial.Polynomial).coef
    out = np.zeros(degree + 1)
    out[: len(coef)] = coef
    return out


def update_sensor_model(params: Params, batch: Batch, post: Posterior, rng: np.random.Generator,
                        method: str = "sample", n_samples: int = 1, degree: int = 3) -> SensorModel:
    """New SensorModel from the used sightings: f by ``fit_polynomial``, sigma_height =
    sqrt(weighted mean of (f(d) - o1)^2), sigma_angle = sqrt(weighted mean of
    wrap(bearing - o2)^2), distance_range_mm = (min, max) of the distances at the smoothed means.
    """
    dist, bearing, obs, w = sensor_points(params, batch, post, rng, method, n_samples)
    coef = fit_polynomial(dist, obs[:, 0], w, degree)
    wsum = w.sum()
    res_h = np.polynomial.polynomial.polyval(dist, coef) - obs[:, 0]
    res_a = geometry.wrap(bearing - obs[:, 1])
    sigma_h = float(np.sqrt(np.sum(w * res_h**2) / wsum))
    sigma_a = float(np.sqrt(np.sum(w * res_a**2) / wsum))
    frames, pose = _used_end_poses(batch)
    dm = np.hypot(batch.beacon_xy[frames, 0] - post.mu_gamma[pose, 0], batch.beacon_xy[frames, 1] - post.mu_gamma[pose, 1])
    return SensorModel(coef, sigma_h, sigma_a, (float(dm.min()), float(dm.max())))
