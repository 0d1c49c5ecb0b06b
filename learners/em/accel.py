"""SQUAREM acceleration of EM (Varadhan & Roland, 2008), on a scaled, unconstrained parameter vector.

EM's map theta -> M(theta) converges linearly; SQUAREM takes two EM steps, r = theta1 - theta0,
v = theta2 - 2 theta1 + theta0, and jumps to theta0 - 2 a r + a^2 v with the step length
a = -|r| / |v| (scheme S3), clamped to [-A_MAX, -1] (a = -1 is plain EM's theta2).

The vector holds what EM estimates, scaled so that one unit is about one "noise width":
per-action displacements divided by the motion std, the sensor curve as heights (px) at four
Chebyshev distances divided by sigma_height, log sigmas, and the log-Cholesky factor of Sigma_A.
The initial states are not extrapolated (they come from the last EM step).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from learners.em.params import ActionModel, Params, SensorModel
from learners.em.sensor_mstep import fit_polynomial

A_MAX = 64.0  # steps were pinned at 8 in measurements; 64 cut iterations ~15%


def _nodes(rng: tuple[float, float]) -> np.ndarray:
    c, h = (rng[0] + rng[1]) / 2, (rng[1] - rng[0]) / 2
    return c + h * np.cos(np.pi * (np.arange(4) + 0.5) / 4)


def _chol_vec(cov: np.ndarray) -> np.ndarray:
    L = np.linalg.cholesky(cov)
    return np.array([np.log(L[0, 0]), np.log(L[1, 1]), np.log(L[2, 2]), L[1, 0], L[2, 0], L[2, 1]])


def _chol_mat(v: np.ndarray) -> np.ndarray:
    L = np.diag(np.exp(v[:3]))
    L[1, 0], L[2, 0], L[2, 1] = v[3], v[4], v[5]
    return L @ L.T


class Packer:
    """Maps Params to and from the scaled vector. The scales are constants (the paper's motion
    std, the recognition range, 1 px), so a resumed fit extrapolates exactly as an unbroken one."""

    MOTION_STD = np.array([10.0, 10.0, 0.1])
    NODES = _nodes((1275.0, 4175.0))
    HEIGHT_SCALE = 1.0

    def __init__(self, learn_noise: bool, degree: int = 3):
        self.learn_noise = learn_noise
        self.degree = degree
        self.motion_std, self.nodes, self.height_scale = self.MOTION_STD, self.NODES, self.HEIGHT_SCALE

    def pack(self, p: Params) -> np.ndarray:
        parts = [
            (p.action.disp / self.motion_std).ravel(),
            p.sensor.height(self.nodes) / self.height_scale,
            np.log([p.sensor.sigma_height, p.sensor.sigma_angle]),
        ]
        if self.learn_noise:
            parts.append(_chol_vec(p.action.cov))
        return np.concatenate(parts)

    def unpack(self, x: np.ndarray, like: Params) -> Params:
        """Params from ``x``; initial states and the distance range are taken from ``like``."""
        n = like.action.disp.size
        disp = x[:n].reshape(like.action.disp.shape) * self.motion_std
        heights = x[n:n + 4] * self.height_scale
        if self.degree == 3:
            coef = fit_polynomial(self.nodes, heights, np.ones(4), 3)
        else:  # other degrees are not extrapolated
            coef = like.sensor.coef
        sh, sa = np.exp(x[n + 4:n + 6])
        cov = _chol_mat(x[n + 6:n + 12]) if self.learn_noise else like.action.cov
        return replace(
            like,
            action=ActionModel(disp, cov, like.action.dt),
            sensor=SensorModel(coef, float(sh), float(sa), like.sensor.distance_range_mm),
        )


def squarem_step(x0: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> tuple[np.ndarray, float]:
    """The S3 extrapolation from three successive EM iterates; returns (x', step length a)."""
    r = x1 - x0
    v = x2 - x1 - r
    nv = np.linalg.norm(v)
    if nv == 0.0:
        return x2, -1.0
    a = float(np.clip(-np.linalg.norm(r) / nv, -A_MAX, -1.0))
    return x0 - 2 * a * r + a * a * v, a
