"""The onboard EKF of :class:`~aibo_gym.policies.localizer.EKFLocalizer` in plain Python floats.

The same equations (prediction with an inflated motion noise, the nominal pinhole and bearing
update, chi-square gate, Joseph form), about 5x faster on 3 x 3 matrices than NumPy: the
exploration rewards run it every frame. Equal to ``EKFLocalizer`` to rounding.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..robot import wrap_angle
from .localizer import NOMINAL_HEIGHT_PX_MM


class FastEKF:
    """EKF on (x mm, y mm, theta rad); ``mean``/``cov`` are NumPy copies, ``m``/``P`` the live floats."""

    def __init__(self, beacons: Sequence[Sequence[float]], sigma_height: float = 1.0, sigma_angle: float = 0.5,
                 slip_std: Sequence[float] = (3.0, 3.0, 0.02), rel_motion_std: float = 0.3, gate: float = 13.8,
                 height_px_mm: float = NOMINAL_HEIGHT_PX_MM) -> None:
        self.beacons = [(float(b[0]), float(b[1])) for b in beacons]
        self.r_h = max(sigma_height, 0.5) ** 2
        self.r_a = max(sigma_angle, 0.03) ** 2
        self.slip = [float(v) for v in slip_std]
        self.rel = float(rel_motion_std)
        self.gate = float(gate)
        self.k = float(height_px_mm)
        self.reset((0.0, 0.0, 0.0), (100.0, 100.0, 0.1))

    def reset(self, pose: Sequence[float], std: Sequence[float] = (100.0, 100.0, 0.1)) -> None:
        self.m = [float(pose[0]), float(pose[1]), float(pose[2])]
        self.P = [[float(std[0]) ** 2, 0.0, 0.0], [0.0, float(std[1]) ** 2, 0.0], [0.0, 0.0, float(std[2]) ** 2]]

    @property
    def mean(self) -> np.ndarray:
        return np.array(self.m)

    @property
    def cov(self) -> np.ndarray:
        return np.array(self.P)

    @property
    def pose(self) -> np.ndarray:
        return np.array([self.m[0], self.m[1], wrap_angle(self.m[2])])

    def logdet(self) -> float:
        P = self.P
        d = (P[0][0] * (P[1][1] * P[2][2] - P[1][2] * P[2][1]) - P[0][1] * (P[1][0] * P[2][2] - P[1][2] * P[2][0])
             + P[0][2] * (P[1][0] * P[2][1] - P[1][1] * P[2][0]))
        return math.log(max(d, 1e-300))

    def predict(self, disp: Sequence[float]) -> None:
        dx, dy, dth = disp
        m, P = self.m, self.P
        c, s = math.cos(m[2]), math.sin(m[2])
        m[0] += c * dx - s * dy
        m[1] += s * dx + c * dy
        m[2] += dth
        f0, f1 = -s * dx - c * dy, c * dx - s * dy  # F = I + [[0,0,f0],[0,0,f1],[0,0,0]]
        # A = F P
        a0 = [P[0][j] + f0 * P[2][j] for j in range(3)]
        a1 = [P[1][j] + f1 * P[2][j] for j in range(3)]
        a2 = P[2]
        # F P F^T
        n00 = a0[0] + a0[2] * f0
        n01 = a0[1] + a0[2] * f1
        n02 = a0[2]
        n11 = a1[1] + a1[2] * f1
        n12 = a1[2]
        n22 = a2[2]
        qx = self.slip[0] + self.rel * abs(dx) + 1.0
        qy = self.slip[1] + self.rel * abs(dy) + 1.0
        qt = self.slip[2] + self.rel * abs(dth) + 0.005
        qx, qy, qt = qx * qx, qy * qy, qt * qt
        # Rt diag(q) Rt^T with Rt = rotation(theta) in x, y
        n00 += c * c * qx + s * s * qy
        n01 += c * s * (qx - qy)
        n11 += s * s * qx + c * c * qy
        n22 += qt
        self.P = [[n00, n01, n02], [n01, n11, n12], [n02, n12, n22]]

    def correct(self, beacon: int, height: float, angle: float) -> bool:
        bx, by = self.beacons[beacon]
        m, P = self.m, self.P
        dx, dy = bx - m[0], by - m[1]
        q = dx * dx + dy * dy
        d = math.sqrt(q)
        if d < 1.0:
            return False
        v0 = height - self.k / d
        v1 = wrap_angle(angle - (math.atan2(dy, dx) - m[2]))
        dh = -self.k / q
        H = ((dh * -dx / d, dh * -dy / d, 0.0), (dy / q, -dx / q, -1.0))
        PH = [[P[i][0] * H[r][0] + P[i][1] * H[r][1] + P[i][2] * H[r][2] for r in range(2)] for i in range(3)]  # P H^T
        s00 = H[0][0] * PH[0][0] + H[0][1] * PH[1][0] + H[0][2] * PH[2][0] + self.r_h
        s01 = H[0][0] * PH[0][1] + H[0][1] * PH[1][1] + H[0][2] * PH[2][1]
        s10 = H[1][0] * PH[0][0] + H[1][1] * PH[1][0] + H[1][2] * PH[2][0]
        s11 = H[1][0] * PH[0][1] + H[1][1] * PH[1][1] + H[1][2] * PH[2][1] + self.r_a
        det = s00 * s11 - s01 * s10
        i00, i01, i10, i11 = s11 / det, -s01 / det, -s10 / det, s00 / det
        if v0 * (i00 * v0 + i01 * v1) + v1 * (i10 * v0 + i11 * v1) > self.gate:
            return False
        K = [[PH[i][0] * i00 + PH[i][1] * i10, PH[i][0] * i01 + PH[i][1] * i11] for i in range(3)]
        for i in range(3):
            m[i] += K[i][0] * v0 + K[i][1] * v1
        # Joseph form: (I - K H) P (I - K H)^T + K R K^T
        A = [[(1.0 if i == j else 0.0) - K[i][0] * H[0][j] - K[i][1] * H[1][j] for j in range(3)] for i in range(3)]
        AP = [[A[i][0] * P[0][j] + A[i][1] * P[1][j] + A[i][2] * P[2][j] for j in range(3)] for i in range(3)]
        N = [[AP[i][0] * A[j][0] + AP[i][1] * A[j][1] + AP[i][2] * A[j][2]
              + K[i][0] * self.r_h * K[j][0] + K[i][1] * self.r_a * K[j][1] for j in range(3)] for i in range(3)]
        self.P = [[0.5 * (N[i][j] + N[j][i]) for j in range(3)] for i in range(3)]
        return True
