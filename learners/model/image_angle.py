"""The true position of a sighting in the image given the observed one: E[phi^2 | phi_obs].

phi_obs = phi + e, e ~ N(0, s^2) (s the bearing's noise, rad). An effect that scales the size by a function of phi
(``off_center_shrink``: 1 - k phi^2) and is fitted on phi_obs^2 is attenuated by the noise (errors in variables); its
expectation given the observation undoes that (regression calibration, Carroll et al. 2006, ch. 4). The expectation
needs a prior for phi. A Gaussian one (phi ~ N(m, v) over the used sightings) is right inside the image and wrong at
its edges: a camera's field of view cuts phi off sharply, so an observation beyond the edge is noise on a phi at the
edge, where the Gaussian prior puts it further out. On simulated wheeled logs (field of view +-0.59 rad, s 0.02 rad)
the Gaussian E[phi^2 | phi_obs] was 0.016-0.037 rad^2 too large for |phi_obs| >= 0.58 (a tenth of a metre of range at
4 m with k 0.45), k came out 1.5% low and a range curve set free bent to absorb it (docs/results.md, "The range curve
freed by default").

Here the prior is the observed angles' histogram deconvolved by the noise (Richardson & Lucy's iteration, the maximum
likelihood density of phi on a grid given the binned phi_obs; ``RL_ITERATIONS``), so a sharp edge stays sharp; the
posterior moments are computed on the grid and interpolated at each sighting. Pure functions of (observed angles, s).
"""

from __future__ import annotations

import numpy as np

#: Richardson-Lucy iterations of the prior (each a convolution of the grid with the noise's kernel)
RL_ITERATIONS = 100
#: grid step as a fraction of the noise's s; the grid spans the used angles +- ``PAD_SD`` s
STEP_PER_SD = 0.5
PAD_SD = 5.0
#: the most grid points: past it (a noise below 1/2000 of the angles' spread: under 0.6 mrad over 1.2 rad; MRCLAM's 3-6
#: mrad take 400-800 points) phi is phi_obs to within the noise, and the moments are those of N(phi_obs, s^2)
MAX_POINTS = 4000


def _kernel() -> np.ndarray:
    """The noise's density on the grid's offsets (+- PAD_SD s, in steps of STEP_PER_SD s), normalized to sum 1: the
    same for every s (an integer number of steps, so a log equal to rounding gets the same kernel)."""
    half = int(round(PAD_SD / STEP_PER_SD))
    x = np.arange(-half, half + 1) * STEP_PER_SD
    k = np.exp(-0.5 * x ** 2)
    return k / k.sum()


KERNEL = _kernel()


def deconvolved_prior(angles: np.ndarray, s: float) -> tuple[np.ndarray, np.ndarray] | None:
    """(grid rad, prior probabilities) of phi from observed ``angles`` (rad) with noise sd ``s`` (rad); None when the
    grid would need more than ``MAX_POINTS`` points or there is nothing to deconvolve."""
    angles = np.asarray(angles, dtype=float)
    if len(angles) < 2 or not s > 0:
        return None
    step = STEP_PER_SD * s
    lo, hi = angles.min() - PAD_SD * s, angles.max() + PAD_SD * s
    n = int(np.ceil((hi - lo) / step)) + 1
    if n > MAX_POINTS:
        return None
    grid = lo + step * np.arange(n)
    # linear binning (each angle's count shared by its two nearest grid points): the prior a continuous function of
    # the angles, so logs equal to rounding give fits equal to rounding
    at = (angles - lo) / step
    left = np.clip(np.floor(at).astype(int), 0, n - 2)
    frac = np.clip(at - left, 0.0, 1.0)
    counts = np.bincount(left, weights=1.0 - frac, minlength=n) + np.bincount(left + 1, weights=frac, minlength=n)
    h = counts / counts.sum()
    p = h
    for _ in range(RL_ITERATIONS):  # p <- p * K^T (h / K p); the kernel is symmetric
        blurred = np.convolve(p, KERNEL, mode="same")
        p = p * np.convolve(np.divide(h, blurred, out=np.zeros(n), where=blurred > 0), KERNEL, mode="same")
        p /= p.sum()
    return grid, p


def phi2_posterior(observed: np.ndarray, used: np.ndarray, s: float) -> np.ndarray:
    """(S,) E[phi^2 | phi_obs] (rad^2) of the ``observed`` angles (rad) under the prior deconvolved from the ``used``
    ones (module docstring). Beyond the grid, or with no grid (``MAX_POINTS``): phi | phi_obs ~ N(phi_obs, s^2), whose
    expectation of phi^2 is phi_obs^2 + s^2."""
    observed = np.asarray(observed, dtype=float)
    mean = observed ** 2 + float(s) ** 2
    prior = deconvolved_prior(used, s)
    if prior is None:
        return mean
    grid, p = prior
    den = np.convolve(p, KERNEL, mode="same")
    ok = den > 1e-12 * den.max()
    g = np.divide(np.convolve(p * grid ** 2, KERNEL, mode="same"), den, out=grid ** 2 + float(s) ** 2, where=ok)
    inside = (observed >= grid[0]) & (observed <= grid[-1])
    mean[inside] = np.interp(observed[inside], grid, g)
    return mean
