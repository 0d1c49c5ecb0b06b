"""A test that the mean of a residual series is the same in every bin, valid for serially correlated residuals.

One-way analysis of variance assumes independent residuals. A smoothed motion residual is correlated with its
neighbours over tens to hundreds of frames (the smoother spreads each sighting's correction over the frames around
it; lag-1 autocorrelation 0.5-0.9 on effect-free simulated logs), so with bins of contiguous frames (elapsed time)
its F-test reports p = 1e-200 on a log with no effect at all.

Here the bin means' covariance is the heteroskedasticity-and-autocorrelation-consistent (Newey-West) one: the
residuals' autocovariance at lags 1..L, each lag's weight 1 - k / (L + 1) (Bartlett kernel), summed over the pairs of
series elements that lag apart in each pair of bins. The Wald statistic W of the q = G - 1 contrasts "bin g minus the
last bin" is referred not to chi-square(q) but to Hotelling's F for a covariance estimated with nu equivalent degrees
of freedom, W (nu - q + 1) / (nu q) ~ F(q, nu - q + 1), nu by Satterthwaite's rule for this estimate: with the
autocovariance estimates' variances of white noise (2 g0^2 / n at lag 0, g0^2 / n beyond), nu = 2 n / (2 + sum_k
(w_k s_k)^2), w_k the Bartlett weight and s_k the lag's share of the contrasts' variance (tr(A_0^-1 A_k) / q). For
contiguous bins (elapsed time) s_k ~ 2 and nu ~ 3 n / (2 L), the Bartlett kernel's (Sun, Phillips and Jin 2008,
Econometrica 76(1)); for bins that interleave (a landmark, a heading) s_k ~ 0 and nu ~ n: the chi-square test as
before. An AR(1) series of lag-1 correlation 0.5 / 0.9 / 0.97 in 8 contiguous bins of 6000 frames (200 series) was
rejected at 5% in 17% / 15% / 33% of series with the chi-square reference, 6.5% / 9% / 16.5% with this one (at 0.9,
another 100 series: 24% and 18%); in interleaved bins 3.5-5% either way. Measured on blind effect-free 5-minute
logs (``scripts/signatures_null.py``; docs/results.md, "Residual signatures on effect-free logs"), logs with any of ~29
signatures at p < 0.001, raw / Holm-adjusted: 10 / 2 -> 5 / 1 of 40 (seeds 6000-6019, both presets), 15 / 5 -> 13 / 3
(6100-6119), 9 raw -> 7 / 1 (6200-6219, generated after the rule was fixed).

The covariance is kept in the Wald form (each bin's own mean taken out of the residuals): in the Lagrange-multiplier
form (the overall mean) the contiguous-bin AR(1) series were rejected in 0.5-2.5%, but an effect inflates that
covariance, so a p-value could not fall below about 1e-4 however large the effect, and the calibrated check, which
reads the signatures' strengths, no longer saw ``beacon_height_scale`` (its "size vs landmark").

The bandwidth L is the larger of Andrews' (1991) plug-in rule for
the Bartlett kernel under an AR(1) approximation, 1.1447 (alpha n)^(1/3), alpha = 4 rho^2 / ((1 - rho)^2 (1 + rho)^2),
rho the lag-1 autocorrelation (capped at ``MAX_RHO``), and ``SQRT_LAGS`` sqrt(n), at most n / 4. The floor: the
residuals' memory is longer than an AR(1)'s of the same lag-1 correlation (the bearing innovations of an effect-free
``paper-sim`` log: lag-1 autocorrelation 0.25, 0.11 at lag 50; block means of 200 sightings vary 28 times more than
independent ones would), and the AR(1) rule alone left "bearing vs elapsed time" at p < 0.001 on 5 of 20 such logs.

For residuals that are independent (the one-step innovations of a sighting) the test is close to the F-test, with a
few lags of noise.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

MAX_RHO = 0.97  # the AR(1) plug-in's lag-1 autocorrelation cap (at 1 the rule's bandwidth is infinite)
SQRT_LAGS = 2.0  # the bandwidth is at least this times sqrt(n) lags (module docstring)


def bandwidth(e: np.ndarray) -> int:
    """The Bartlett kernel's bandwidth (lags) for the demeaned series ``e``: Andrews' AR(1) plug-in, at least
    ``SQRT_LAGS`` sqrt(n) (module docstring)."""
    n = len(e)
    rho = float(np.dot(e[:-1], e[1:]) / max(np.dot(e, e), 1e-300))
    rho = float(np.clip(rho, -MAX_RHO, MAX_RHO))
    alpha = 4.0 * rho ** 2 / ((1.0 - rho) ** 2 * (1.0 + rho) ** 2)
    lags = max(1.1447 * (alpha * n) ** (1.0 / 3.0), SQRT_LAGS * np.sqrt(n))
    return int(np.clip(np.ceil(lags), 1, max(n // 4, 1)))


def contrasts(n_groups: int) -> np.ndarray:
    """(G - 1, G): the contrasts "bin g minus the last bin"."""
    return np.hstack([np.eye(n_groups - 1), -np.ones((n_groups - 1, 1))])


def bin_means(r: np.ndarray, group: np.ndarray, n_groups: int) -> tuple[np.ndarray, np.ndarray, float]:
    """(the bin means, their covariance robust to serial correlation, its equivalent degrees of freedom: module
    docstring) of the series ``r`` (in time order) binned by ``group`` (integers
    0..n_groups-1, each bin non-empty)."""
    r = np.asarray(r, dtype=float)
    g = np.asarray(group, dtype=np.int64)
    n, G = len(r), n_groups
    count = np.bincount(g, minlength=G).astype(float)
    means = np.bincount(g, weights=r, minlength=G) / count
    e = r - means[g]
    lags = bandwidth(e)
    # the contrasts "bin g minus the last" scaled by the counts: the bin means' differences in pair sums
    contrast = contrasts(G) / count
    a0 = contrast @ np.diag(count) @ contrast.T
    a0_inv = np.linalg.pinv(a0)
    cov = np.diag(count) * (np.dot(e, e) / n)  # sums over pairs of elements; divided by the counts below
    spread = 0.0  # sum over lags of (weight x the lag's share of the contrasts' variance)^2: for ``nu``
    for k in range(1, min(lags, n - 1) + 1):
        weight = 1.0 - k / (lags + 1.0)
        pairs = np.bincount(g[:-k] * G + g[k:], minlength=G * G).reshape(G, G)
        cov += np.dot(e[:-k], e[k:]) / n * weight * (pairs + pairs.T)
        spread += (weight * np.trace(a0_inv @ contrast @ (pairs + pairs.T) @ contrast.T) / (G - 1)) ** 2
    return means, cov / np.outer(count, count), 2.0 * n / (2.0 + spread)


def equal_means_p(r: np.ndarray, group: np.ndarray, n_groups: int) -> float:
    """p-value of "every bin has the same mean" for the series ``r`` (in time order) binned by ``group`` (integers
    0..n_groups-1, each bin non-empty), robust to serial correlation (module docstring). 1.0 when the covariance of
    the bin means is singular."""
    return wald_p(*bin_means(r, group, n_groups))


def wald_p(means: np.ndarray, cov: np.ndarray, nu: float) -> float:
    """p-value of the Wald test that every one of ``means`` (with covariance ``cov`` of ``nu`` equivalent degrees of
    freedom) is the same: W (nu - q + 1) / (nu q) ~ F(q, nu - q + 1), q = len(means) - 1; 1.0 when the contrasts'
    covariance is singular."""
    G = len(means)
    q = G - 1
    contrast = contrasts(G)
    d = contrast @ means
    try:
        wald = float(d @ np.linalg.solve(contrast @ cov @ contrast.T, d))
    except np.linalg.LinAlgError:
        return 1.0
    if not (np.isfinite(wald) and wald >= 0) or nu - q + 1 <= 0:
        return 1.0
    return float(stats.f.sf(wald * (nu - q + 1) / (nu * q), q, nu - q + 1))
