"""What the E-step returns: the Gaussian beliefs the M-step statistics consume."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class ExtraMoments:
    """The beliefs of an augmented E-step (``Lowered.extra``) on the whole state x = (pose, K extra states),
    n = 3 + K: what its M-steps need beyond the pose marginals (``learners.inference.augmented``)."""

    filtered_mean: np.ndarray  # (P, n) forward EKF after each pose's sightings (alpha)
    filtered_cov: np.ndarray  # (P, n, n)
    predicted_mean: np.ndarray  # (N, n) each frame's prediction of its end pose, before its sightings
    predicted_cov: np.ndarray  # (N, n, n)
    smoothed_mean: np.ndarray  # (P, n) Rauch-Tung-Striebel (gamma)
    smoothed_cov: np.ndarray  # (P, n, n)
    cross: np.ndarray  # (N, K) Cov(b_p, b_{p+1} | all data) of each extra state over each frame

    @property
    def mean(self) -> np.ndarray:
        """(P, K) smoothed means of the extra states."""
        return self.smoothed_mean[:, 3:]

    @property
    def var(self) -> np.ndarray:
        """(P, K) smoothed variances of the extra states."""
        return np.diagonal(self.smoothed_cov[:, 3:, 3:], axis1=1, axis2=2)


@dataclass
class Posterior:
    """E-step output for a Batch with N frames, S sightings, L logs and P = N + L poses.

    alpha: forward EKF (filtered) beliefs; gamma: smoothed beliefs (equations (1)-(2));
    delta: b(s_t, o_t) * beta_t(s_t) in information form (it is improper, Sigma = inf,
    until enough sightings constrain all three state dimensions). Pose-indexed arrays
    have P rows; delta is indexed by frame (row i is the END pose of frame i, with all of
    frame i's applied sightings). Units: mm, mm, rad; heading kept unwrapped in every mean.
    With extra states (``Lowered.extra``) the arrays above are the pose marginals of the augmented
    beliefs, delta is not formed, and ``extra`` holds the rest.
    """

    mu_alpha: np.ndarray  # (P, 3)
    cov_alpha: np.ndarray  # (P, 3, 3)
    mu_gamma: np.ndarray  # (P, 3)
    cov_gamma: np.ndarray  # (P, 3, 3)
    info_delta: np.ndarray | None  # (N, 3, 3)  Y_delta (None from the augmented E-step: see ``extra``)
    vec_delta: np.ndarray | None  # (N, 3)     y_delta
    loglik: float  # log p(O | lambda): sum of the applied sightings' sequential predictive log densities
    mahal2: np.ndarray  # (S,) squared Mahalanobis distance of each sighting's innovation; NaN if not used
    extra: ExtraMoments | None = None  # the augmented E-step's moments (RTS smoother), None otherwise
