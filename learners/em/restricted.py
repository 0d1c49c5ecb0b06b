"""The motion noise at the restricted likelihood's maximum (REML), for ``EMOptions.restricted_noise``.

EM maximizes the likelihood over the velocities and the motion noise Sigma_A together, and the velocities are fitted
from the same path the noise is measured on. On a short log whose commands each run in a few blocks (the `aibo`
preset's 5-minute logs: each of the 40 commands in one or two blocks of 5 s) a command's velocities take up the
path's wander over its blocks, and the noise left for the path is far too small: the position noise's variance at the
likelihood's maximum had a median of 1.6 mm^2 per frame for the true 9 on 50 such logs, 1.7 on an effect-free one
(seed 8058), where EM with the velocities held at the truth gives 8.0 and 6.7. It is maximum likelihood's bias for a
variance that shares its data with fitted means (Patterson & Thompson 1971; Harville 1977), here large because the
path is seen only through the sightings. A path held that stiff overstates what the log says of every parameter the
path's wander could mimic: `floor_drift`'s 95% intervals held the drift along it on 76% of those logs, on 92% with
the noise held at the truth; ``aibo diagnose``'s own intervals 82%, and 87% with this (docs/results.md, "The motion
noise at the likelihood's maximum").

The restricted likelihood integrates the mean parameters out; with them entering the path linearly, Laplace's
approximation is exact, and it is the profile likelihood adjusted by their information (Cox & Reid 1987):

    l_R(c) = l(c, theta_c) - 1/2 log det I_theta(c),

theta every coordinate but the variances (the motion noise and the sensor's sigmas): the velocities, the sensor
curve, the effects' parameters and the start poses; theta_c their fit (EM with the noise held) where the motion
noise's position block is c times the fit's (the heading's, which the bearings fix, is kept); I_theta(c) their Fisher
information there (``learners.em.uncertainty.parameter_uncertainty``, the noise's coordinates held). Maximized over
log c by golden section on [``SCALE_LOW``, ``SCALE_HIGH``]; each point is one EM fit warm-started from the fit and one
pass of the filter per coordinate of theta.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, Callable

import numpy as np

from aibo_core.trajectory import Trajectory
from learners.em.options import EMOptions
from learners.model.model import Model

SCALE_LOW, SCALE_HIGH = 0.25, 16.0  # the position noise's variance, times the maximum likelihood fit's
EVALUATIONS = 10  # points of the golden section (its last bracket spans a factor 1.09 of the scale)
#: the variances, which the restricted likelihood does not integrate out (``Model.packed_layout`` names)
VARIANCES = ("action.cov", "sensor.sigma_size", "sensor.sigma_bearing")
_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


def scaled_noise(model: Model, c: float) -> Model:
    """``model`` with its motion noise's position block (x, y rows and columns) times ``c``, the heading's kept."""
    d = np.array([math.sqrt(c), math.sqrt(c), 1.0])
    cov = np.asarray(model.action.cov, dtype=float) * np.outer(d, d)
    return model.with_(action=model.action.with_values(cov=cov))


def held_noise(opts: EMOptions) -> EMOptions:
    """``opts`` for fits with the motion noise held where it is (at the restricted maximum): the fit's stop rule."""
    return replace(opts, learn_motion_noise=False, restricted_noise=False)


def log_information(model: Model, logs: list[Trajectory], fixed: frozenset[str]) -> float:
    """log det of the Fisher information of ``model``'s coordinates other than ``fixed`` on ``logs``, over the
    directions the logs determine (eigenvalues above 1e-10 of the largest: an undetermined direction does not count)."""
    from learners.arrays.batch import make_batch
    from learners.em.uncertainty import parameter_uncertainty

    info = parameter_uncertainty(model, make_batch(logs), fixed=fixed).information
    eig = np.linalg.eigvalsh(0.5 * (info + info.T))
    return float(np.sum(np.log(eig[eig > 1e-10 * eig.max()])))


def golden_max(f: Callable[[float], float], low: float, high: float, evaluations: int) -> float:
    """The argument of ``f``'s maximum on [low, high] by golden-section search (``f`` unimodal there) with
    ``evaluations`` calls; the best point evaluated."""
    seen: dict[float, float] = {}

    def g(x: float) -> float:
        seen[x] = f(x)
        return seen[x]

    a, b = low, high
    x1, x2 = b - _GOLDEN * (b - a), a + _GOLDEN * (b - a)
    f1, f2 = g(x1), g(x2)
    for _ in range(max(evaluations - 2, 0)):
        if f1 > f2:
            b, x2, f2 = x2, x1, f1
            x1 = b - _GOLDEN * (b - a)
            f1 = g(x1)
        else:
            a, x1, f1 = x1, x2, f2
            x2 = a + _GOLDEN * (b - a)
            f2 = g(x2)
    return max(seen, key=seen.__getitem__)


def restricted_noise(model: Model, logs: list[Trajectory], opts: EMOptions) -> tuple[Model, dict[str, Any]]:
    """(the fit at the restricted likelihood's maximum over the motion noise's position scale, what was done):
    ``model`` a converged fit of ``logs`` with ``opts`` (module docstring). The record: ``scale`` (c), ``bound``
    (whether c is at an end of the bracket), the position noise's sd per frame before and after (mm, x and y), and the
    restricted log-likelihood's gain over c = 1 (nats)."""
    from learners.discrepancy.fitting import train_loglik
    from learners.em.accel import Packer
    from learners.em.learner import EMLearner

    fit_opts = replace(held_noise(opts), uncertainty=False, polish=False)
    fixed = Packer(fit_opts).fixed | frozenset(VARIANCES)
    fits: dict[float, tuple[float, Model]] = {}

    def restricted(log_c: float) -> float:
        m = EMLearner(fit_opts, check_field=False).fit(logs, init=scaled_noise(model, math.exp(log_c))).params
        value = train_loglik(m, logs) - 0.5 * log_information(m, logs, fixed)
        fits[log_c] = (value, m)
        return value

    best = golden_max(restricted, math.log(SCALE_LOW), math.log(SCALE_HIGH), EVALUATIONS)
    at_one = restricted(0.0)
    bound = best - math.log(SCALE_LOW) < 0.1 or math.log(SCALE_HIGH) - best < 0.1
    return fits[best][1], {"scale": math.exp(best), "bound": bool(bound),
                           "position_noise_sd_mm": {"maximum_likelihood": position_sd(model),
                                                    "restricted": position_sd(fits[best][1])},
                           "gain_nats": float(fits[best][0] - at_one)}


def position_sd(model: Model) -> list[float]:
    """The motion noise's position sd per frame (mm, x and y), to the micrometre."""
    return np.sqrt(np.diag(np.asarray(model.action.cov, dtype=float))[:2]).round(3).tolist()
