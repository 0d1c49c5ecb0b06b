"""What the E-step returns: the Gaussian beliefs the M-step statistics consume."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Posterior:
    """E-step output for a Batch with N frames, S sightings, L logs and P = N + L poses.

    alpha: forward EKF (filtered) beliefs; gamma: smoothed beliefs (equations (1)-(2));
    delta: b(s_t, o_t) * beta_t(s_t) in information form (it is improper, Sigma = inf,
    until enough sightings constrain all three state dimensions). Pose-indexed arrays
    have P rows; delta is indexed by frame (row i is the END pose of frame i, with all of
    frame i's applied sightings). Units: mm, mm, rad; heading kept unwrapped in every mean.
    """

    mu_alpha: np.ndarray  # (P, 3)
    cov_alpha: np.ndarray  # (P, 3, 3)
    mu_gamma: np.ndarray  # (P, 3)
    cov_gamma: np.ndarray  # (P, 3, 3)
    info_delta: np.ndarray  # (N, 3, 3)  Y_delta
    vec_delta: np.ndarray  # (N, 3)     y_delta
    loglik: float  # log p(O | lambda): sum of the applied sightings' sequential predictive log densities
    mahal2: np.ndarray  # (S,) squared Mahalanobis distance of each sighting's innovation; NaN if not used
