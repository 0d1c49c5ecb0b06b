"""SQUAREM acceleration of EM (Varadhan & Roland, 2008), on a scaled, unconstrained parameter vector.

EM's map theta -> M(theta) converges linearly; SQUAREM takes two EM steps, r = theta1 - theta0,
v = theta2 - 2 theta1 + theta0, and jumps to theta0 - 2 a r + a^2 v with the step length
a = -|r| / |v| (scheme S3), clamped to [-A_MAX, -1] (a = -1 is plain EM's theta2).

The vector holds what EM estimates, scaled so that one unit is about one "noise width"
(``learners.model.parameters``): the action weights divided by the paper's motion std, the sensor
curve as its values (px) at Chebyshev distances, log sigmas, effect parameters, and the
log-Cholesky factor of Sigma_A. The initial states are not extrapolated (they come from the last
EM step).
"""

from __future__ import annotations

import numpy as np

from learners.em.options import EMOptions
from learners.model.model import Model

A_MAX = 64.0  # steps were pinned at 8 in measurements; 64 cut iterations ~15%


def _params_of(effect_name: str) -> tuple[str, ...]:
    from learners.model.effects import EFFECT_MODELS

    return tuple(EFFECT_MODELS[effect_name].PARAMS) if effect_name in EFFECT_MODELS else ()


class Packer:
    """Maps a Model to and from the scaled vector (``Model.pack``: every trainable parameter in its
    component's declared transform; the motion covariance only when it is learned). The scales are
    constants, so a resumed fit extrapolates exactly as an unbroken one."""

    def __init__(self, opts: "EMOptions"):
        fixed = set() if opts.learn_motion_noise else {"action.cov"}
        if opts.hold_curve:
            fixed.add("sensor.coef")
        self.fixed = frozenset(fixed | {f"effects.{name}.{p}" for name in opts.frozen for p in _params_of(name)})

    def pack(self, p: Model) -> np.ndarray:
        return p.pack(self.fixed)

    def unpack(self, x: np.ndarray, like: Model) -> Model:
        """A model from ``x``; initial states and the distance range are taken from ``like``."""
        return like.unpack(x, self.fixed)


def squarem_step(x0: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> tuple[np.ndarray, float]:
    """The S3 extrapolation from three successive EM iterates; returns (x', step length a)."""
    r = x1 - x0
    v = x2 - x1 - r
    nv = np.linalg.norm(v)
    if nv == 0.0:
        return x2, -1.0
    a = float(np.clip(-np.linalg.norm(r) / nv, -A_MAX, -1.0))
    return x0 - 2 * a * r + a * a * v, a
