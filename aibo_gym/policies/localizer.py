"""An onboard EKF localizer: the pose estimate a real robot could have, without privileged pose.

It predicts with the *attempted* velocities scaled to the nominal maxima (what the robot believes
its actions do) and corrects with sightings through the *nominal* pinhole sensor model
(height px = 57000 / d, d in mm) and the beacon bearing from the body heading, with the beacon
positions known. The motion noise is inflated (``rel_motion_std``) because the true action model
differs from the nominal one; innovations beyond a chi-square gate are ignored.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..robot import wrap_angle

NOMINAL_HEIGHT_PX_MM = 57000.0  # focal 190 px * beacon height 300 mm


class EKFLocalizer:
    """Extended Kalman filter on the pose (x mm, y mm, theta rad)."""

    def __init__(
        self,
        beacons: Sequence[Sequence[float]],
        sigma_height: float = 1.0,
        sigma_angle: float = 0.5,
        slip_std: Sequence[float] = (3.0, 3.0, 0.02),
        rel_motion_std: float = 0.3,
        gate: float = 13.8,
        height_px_mm: float = NOMINAL_HEIGHT_PX_MM,
    ) -> None:
        self.beacons = np.asarray(beacons, dtype=float)
        self.R = np.diag([max(sigma_height, 0.5) ** 2, max(sigma_angle, 0.03) ** 2])
        self.slip_std = np.asarray(slip_std, dtype=float)
        self.rel_motion_std = rel_motion_std
        self.gate = gate  # chi-square, 2 dof (13.8 ~ p = 0.001)
        self.k = height_px_mm
        self.mean = np.zeros(3)
        self.cov = np.diag([1e4, 1e4, 1e-2])

    @property
    def pose(self) -> np.ndarray:
        """Current estimate (x mm, y mm, theta rad in (-pi, pi])."""
        return np.array([self.mean[0], self.mean[1], wrap_angle(self.mean[2])])

    def reset(self, pose: Sequence[float], std: Sequence[float] = (100.0, 100.0, 0.1)) -> None:
        """Start at ``pose`` with independent standard deviations ``std`` (mm, mm, rad)."""
        self.mean = np.asarray(pose, dtype=float).copy()
        self.cov = np.diag(np.square(np.asarray(std, dtype=float)))

    def predict(self, disp: Sequence[float]) -> None:
        """Time update with a believed robot-frame displacement ``disp`` (mm, mm, rad per frame)."""
        dx, dy, dth = disp
        th = self.mean[2]
        c, s = math.cos(th), math.sin(th)
        self.mean = self.mean + np.array([c * dx - s * dy, s * dx + c * dy, dth])
        F = np.eye(3)
        F[0, 2] = -s * dx - c * dy
        F[1, 2] = c * dx - s * dy
        q = self.slip_std + self.rel_motion_std * np.abs(disp) + np.array([1.0, 1.0, 0.005])
        Rt = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        self.cov = F @ self.cov @ F.T + Rt @ np.diag(q * q) @ Rt.T

    def correct(self, beacon: int, height: float, angle: float) -> bool:
        """Measurement update with a sighting (beacon index, height px, angle rad). False if gated out."""
        bx, by = self.beacons[beacon]
        x, y, th = self.mean
        dx, dy = bx - x, by - y
        q = dx * dx + dy * dy
        d = math.sqrt(q)
        if d < 1.0:
            return False
        v = np.array([height - self.k / d, wrap_angle(angle - (math.atan2(dy, dx) - th))])
        dh = -self.k / q  # d height / d distance
        H = np.array([[dh * -dx / d, dh * -dy / d, 0.0], [dy / q, -dx / q, -1.0]])
        S = H @ self.cov @ H.T + self.R
        Sinv = np.linalg.inv(S)
        if float(v @ Sinv @ v) > self.gate:
            return False
        K = self.cov @ H.T @ Sinv
        self.mean = self.mean + K @ v
        IKH = np.eye(3) - K @ H
        self.cov = IKH @ self.cov @ IKH.T + K @ self.R @ K.T
        self.cov = 0.5 * (self.cov + self.cov.T)
        return True
