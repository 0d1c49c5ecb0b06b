"""A test that the mean of a residual series is the same in every bin, valid for serially correlated residuals.

One-way analysis of variance assumes independent residuals. A smoothed motion residual is correlated with its
neighbours over tens to hundreds of frames (the smoother spreads each sighting's correction over the frames around
it; lag-1 autocorrelation 0.5-0.9 on effect-free simulated logs), so with bins of contiguous frames (elapsed time)
its F-test reports p = 1e-200 on a log with no effect at all.

Here the bin means' covariance is the heteroskedasticity-and-autocorrelation-consistent (Newey-West) one: the
residuals' autocovariance at lags 1..L, each lag's weight 1 - k / (L + 1) (Bartlett kernel), summed over the pairs of
series elements that lag apart in each pair of bins. The Wald statistic of the G - 1 contrasts "bin g minus the last
bin" is then chi-square(G - 1) under equal means. The bandwidth L is the larger of Andrews' (1991) plug-in rule for
the Bartlett kernel under an AR(1) approximation, 1.1447 (alpha n)^(1/3), alpha = 4 rho^2 / ((1 - rho)^2 (1 + rho)^2),
rho the lag-1 autocorrelation (capped at ``MAX_RHO``), and ``SQRT_LAGS`` sqrt(n), at most n / 4. The floor: the
residuals' memory is longer than an AR(1)'s of the same lag-1 correlation (the bearing innovations of an effect-free
``paper-sim`` log: lag-1 autocorrelation 0.25, 0.11 at lag 50; block means of 200 sightings vary 28 times more than
independent ones would), and the AR(1) rule alone left "bearing vs elapsed time" at p < 0.001 on 5 of 20 such logs.

For residuals that are independent (the one-step innovations of a sighting) the test is the F-test's large-sample
chi-square version with a few lags of noise.
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


def bin_means(r: np.ndarray, group: np.ndarray, n_groups: int) -> tuple[np.ndarray, np.ndarray]:
    """(the bin means, their covariance robust to serial correlation: module docstring) of the series ``r`` (in time
    order) binned by ``group`` (integers 0..n_groups-1, each bin non-empty)."""
    r = np.asarray(r, dtype=float)
    g = np.asarray(group, dtype=np.int64)
    n, G = len(r), n_groups
    count = np.bincount(g, minlength=G).astype(float)
    means = np.bincount(g, weights=r, minlength=G) / count
    e = r - means[g]
    lags = bandwidth(e)
    cov = np.diag(count) * (np.dot(e, e) / n)  # sums over pairs of elements; divided by the counts below
    for k in range(1, min(lags, n - 1) + 1):
        gamma = np.dot(e[:-k], e[k:]) / n * (1.0 - k / (lags + 1.0))
        pairs = np.bincount(g[:-k] * G + g[k:], minlength=G * G).reshape(G, G)
        cov += gamma * (pairs + pairs.T)
    return means, cov / np.outer(count, count)


def equal_means_p(r: np.ndarray, group: np.ndarray, n_groups: int) -> float:
    """p-value of "every bin has the same mean" for the series ``r`` (in time order) binned by ``group`` (integers
    0..n_groups-1, each bin non-empty), robust to serial correlation (module docstring). 1.0 when the covariance of
    the bin means is singular."""
    means, cov = bin_means(r, group, n_groups)
    return wald_p(means, cov)


def wald_p(means: np.ndarray, cov: np.ndarray) -> float:
    """p-value of the Wald test that every one of ``means`` (with covariance ``cov``) is the same; 1.0 when the
    contrasts' covariance is singular."""
    G = len(means)
    contrast = np.hstack([np.eye(G - 1), -np.ones((G - 1, 1))])
    d = contrast @ means
    try:
        wald = float(d @ np.linalg.solve(contrast @ cov @ contrast.T, d))
    except np.linalg.LinAlgError:
        return 1.0
    return float(stats.chi2.sf(wald, G - 1)) if np.isfinite(wald) and wald >= 0 else 1.0
