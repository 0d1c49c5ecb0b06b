"""What the E-step returns: the Gaussian beliefs the M-step consumes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Posterior:
    """E-step output for a Batch with N frames, S logs and P = N + S poses.

    alpha: forward EKF (filtered) beliefs; gamma: smoothed beliefs (equations (1)-(2));
    delta: b(s_t, o_t) * beta_t(s_t) in information form (it is improper, Sigma = inf,
    until enough sightings constrain all three state dimensions). Pose-indexed arrays
    have P rows; delta is indexed by frame (row i is the END pose of frame i).
    Heading is kept unwrapped in every mean.
    """

    mu_alpha: np.ndarray  # (P, 3)
    cov_alpha: np.ndarray  # (P, 3, 3)
    mu_gamma: np.ndarray  # (P, 3)
    cov_gamma: np.ndarray  # (P, 3, 3)
    info_delta: np.ndarray  # (N, 3, 3)  Y_delta
    vec_delta: np.ndarray  # (N, 3)     y_delta
    loglik: float  # log p(O | lambda), full one-step predictive (see smoother.py)
    mahal2: np.ndarray  # (N,) squared Mahalanobis distance of each sighting's innovation; NaN if none
