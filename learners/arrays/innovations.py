"""Sightings' innovations under a Gaussian prediction of the pose: what a sighting's predictive density is made of.

A sighting z = (size, bearing) predicted from a pose belief N(m, P) has the innovation v = z - h(m) (size in px or
mm, bearing in rad, wrapped) and the covariance S = H P H^T + R: the predicted pose's share H P H^T and the sensor's
own noise R (diagonal: the size and bearing variances, each sighting's variance factors applied). Kept apart, they
let an effect that changes the sensor's noise alone (a scale mixture: ``heavy_tailed_noise``) evaluate the density
with R scaled and the pose's share held; ``logdens()`` is the Gaussian predictive log density itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LOG_2PI = float(np.log(2.0 * np.pi))


@dataclass(frozen=True)
class Innovations:
    """n sightings' innovations (module docstring)."""

    v: np.ndarray  # (n, 2) z - h(m): size (px or mm), bearing (rad, wrapped)
    hph: np.ndarray  # (n, 3) the entries s00, s01, s11 of H P H^T (the predicted pose's share)
    r: np.ndarray  # (n, 2) the sensor's own size and bearing variances (R's diagonal)

    def logdens(self, noise_factor: float | np.ndarray = 1.0) -> np.ndarray:
        """(n,) log N(v; 0, H P H^T + noise_factor R), ``noise_factor`` a number or one per sighting."""
        s00 = self.hph[:, 0] + noise_factor * self.r[:, 0]
        s11 = self.hph[:, 2] + noise_factor * self.r[:, 1]
        s01 = self.hph[:, 1]
        v0, v1 = self.v[:, 0], self.v[:, 1]
        det = s00 * s11 - s01 * s01
        m2 = (s11 * v0 * v0 - 2.0 * s01 * v0 * v1 + s00 * v1 * v1) / det
        return -0.5 * (m2 + np.log(det) + 2.0 * LOG_2PI)

    def take(self, mask: np.ndarray) -> "Innovations":
        """The sightings selected by ``mask`` (boolean or indices)."""
        return Innovations(self.v[mask], self.hph[mask], self.r[mask])


def innovations_from_s(v: np.ndarray, S: np.ndarray, r: np.ndarray) -> Innovations:
    """Innovations from the whole covariance S (n, 2, 2) = H P H^T + R and R's diagonal ``r`` (n, 2)."""
    s01 = 0.5 * (S[:, 0, 1] + S[:, 1, 0])
    return Innovations(v, np.stack([S[:, 0, 0] - r[:, 0], s01, S[:, 1, 1] - r[:, 1]], axis=1), r)
