"""Parameters of the robot's models: small typed containers, no algorithms.

Units: displacements are per frame in the robot frame (mm, mm, rad); velocities
(mm/s, mm/s, rad/s) are ``displacement / dt``. Distances are mm, heights px,
angles rad.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

N_ACTIONS = 40

#: The paper's fixed per-frame motion noise: 10 mm, 10 mm, 0.1 rad standard deviations (footnote 2).
PAPER_MOTION_STD = (10.0, 10.0, 0.1)


@dataclass(frozen=True)
class ActionModel:
    """Mean relative displacement per frame for each action, and the per-frame noise.

    ``disp[a] = (dx mm, dy mm, dtheta rad)`` in the frame of the pose at the start of the
    frame; ``cov`` (3, 3) is Sigma_A, the covariance of that displacement (shared by all
    actions, as in the paper).
    """

    disp: np.ndarray  # (40, 3)
    cov: np.ndarray  # (3, 3)
    dt: float

    @property
    def velocities(self) -> np.ndarray:
        """(40, 3) velocities: vx mm/s, vy mm/s, vtheta rad/s."""
        return self.disp / self.dt

    @staticmethod
    def from_velocities(vel: np.ndarray, dt: float, std=PAPER_MOTION_STD) -> "ActionModel":
        return ActionModel(np.asarray(vel, float) * dt, np.diag(np.square(np.asarray(std, float))), float(dt))


@dataclass(frozen=True)
class SensorModel:
    """Beacon height ~ N(f(d), sigma_height^2), angle ~ N(bearing, sigma_angle^2).

    ``coef`` are the polynomial coefficients of f in ascending powers of the distance
    d in mm: ``f(d) = sum_k coef[k] * d**k`` (px).
    """

    coef: np.ndarray
    sigma_height: float
    sigma_angle: float
    distance_range_mm: tuple[float, float] = (1275.0, 4175.0)

    def height(self, d: np.ndarray) -> np.ndarray:
        """f(d) in px for distances d in mm (Horner's rule)."""
        return np.polynomial.polynomial.polyval(np.asarray(d, float), self.coef)

    def dheight(self, d: np.ndarray) -> np.ndarray:
        """f'(d) in px/mm."""
        return np.polynomial.polynomial.polyval(np.asarray(d, float), np.polynomial.polynomial.polyder(self.coef))


@dataclass(frozen=True)
class InitialState:
    """pi: Gaussian over the first pose (x mm, y mm, theta rad)."""

    mean: np.ndarray  # (3,)
    cov: np.ndarray  # (3, 3)


#: Default start pose belief: the env's start (field centre, facing +x) with 100 mm / 0.1 rad std.
DEFAULT_INITIAL = InitialState(np.zeros(3), np.diag([100.0**2, 100.0**2, 0.1**2]))

#: The paper's starting sensor model: a very poor line, sigma_height 10 px, sigma_angle 0.2 rad.
#: The line 40 - 0.005 d puts beacons at distances that fit the field (see the README).
PAPER_START_SENSOR = SensorModel(np.array([40.0, -0.005]), 10.0, 0.2)


@dataclass(frozen=True)
class Params:
    """lambda = (a, b, pi): everything EM estimates. One InitialState per log."""

    action: ActionModel
    sensor: SensorModel
    init: tuple[InitialState, ...]

    def with_(self, **kw) -> "Params":
        return replace(self, **kw)


def paper_start(dt: float, n_logs: int = 1) -> Params:
    """The paper's start: all velocities zero, a very poor linear sensor model."""
    return Params(
        ActionModel.from_velocities(np.zeros((N_ACTIONS, 3)), dt),
        PAPER_START_SENSOR,
        tuple(DEFAULT_INITIAL for _ in range(n_logs)),
    )
