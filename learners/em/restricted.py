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


# --------------------------------------------------------------------------- the effects' variance parameters
# The same bias moves a named effect's variance parameters (``EffectModel.VARIANCE_PARAMS``: a bias process's sd and
# correlation time): on the calibration study's 5-minute `aibo` logs of ``landmark_bias`` (sigma_rel 0.05, tau_s 8 s)
# the final fit's sigma_rel averages 7% short (-0.92 standard errors; 80% of its 95% intervals hold 0.05), and with
# the 40 commands' velocities held at the truth it is 1.2% short. Those parameters sit within about a standard error
# of the restricted maximum, where a Newton step on l_R reaches it: at the maximum likelihood fit the profile's
# gradient is 0, so the step is -1/2 V grad_v log det I_theta, V their block of the inverse information (the
# profile's curvature, the rest refitted) and the gradient by central differences with theta held. Measured
# (docs/results.md, "A bias process's sd by restricted likelihood"): on the `aibo` logs of seeds 8000-8010 (even) the
# step over (sigma_rel, tau_s) gives 0.0519 / 0.0481 / 0.0496 / 0.0507 / 0.0523 / 0.0497 where the velocities held at
# the truth give 0.0504 / 0.0477 / 0.0496 / 0.0502 / 0.0510 / 0.0477; over sigma_rel alone it overshoots (tau_s moves
# with it along their ridge). On `paper-sim`'s 0.5 rad bearings the likelihood falls about twice as fast along the
# step as the information says and the restricted likelihood, computed exactly along it, peaks at 0.4-0.6 of it: a
# fit held at the step's end measures that fall and shortens the step (``step_length``). The motion noise is not
# stepped (its Cholesky coordinates are far from quadratic there: ``restricted_noise`` searches its scale instead).

DIFFERENCE_STEP = 0.05  # packed units (log scale for a positive parameter): the central difference of log det I_theta
MAX_STEP_SE = 3.0  # a step longer than this many standard errors in any coordinate is not local: not taken


def newton_step(gradient: np.ndarray, covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the step, its length in standard errors per coordinate) of the restricted likelihood's Newton step from the
    likelihood's maximum: -1/2 ``covariance`` @ ``gradient``, ``gradient`` that of log det I_theta over the variance
    coordinates and ``covariance`` their block of the inverse information."""
    step = -0.5 * covariance @ gradient
    return step, step / np.sqrt(np.diag(covariance))


def variance_coordinates(model: Model) -> dict[str, tuple[str, ...]]:
    """Per effect of ``model`` that declares any (``EffectModel.VARIANCE_PARAMS``): its variance parameters."""
    return {e.name: tuple(e.VARIANCE_PARAMS) for e in model.effects if e.VARIANCE_PARAMS}


def step_length(slope: float, drop: float) -> float:
    """The length t in (0, 1] of the Newton step to take: the restricted log-likelihood along the step, l_R(t) = -1/2
    kappa t^2 + ``slope`` t, peaks at t = ``slope`` / kappa; ``slope`` is the adjustment's rise over the whole step
    (nats; equal to the Fisher information's curvature along it, which puts the peak at t = 1) and kappa = 2 ``drop``,
    the likelihood's measured fall over the step (a fit with the parameters held at its end, the rest refitted). A
    fall steeper than the information says shortens the step; a flatter one (or EM's stop noise) never lengthens it."""
    kappa = 2.0 * drop
    return 1.0 if kappa <= slope else slope / kappa


def restricted_step(model: Model, logs: list[Trajectory], opts: EMOptions) -> tuple[Model, dict[str, Any] | None]:
    """(``model`` with its effects' variance parameters moved towards the restricted likelihood's maximum, the record)
    for a maximum likelihood fit ``model`` of ``logs`` with ``opts`` (the coordinates it held: ``Packer(opts).fixed``).
    The step is the Newton step with the Fisher information's curvature, shortened where a fit held at its end shows
    the likelihood falling faster (``step_length``: on `paper-sim`'s 0.5 rad bearings it fell 1.9 times faster, and the
    restricted likelihood along the step peaked at 0.4-0.6 of it). The record, None where no effect declares any
    variance parameter: {"effects": {name: {param: {"maximum_likelihood", "restricted"}}}, "step_se": {coordinate:
    the whole Newton step in standard errors}, "length": the share of it taken, "taken": bool, "why": "" or why not
    taken}. Not taken where the Newton step is longer than ``MAX_STEP_SE`` standard errors in any coordinate or one
    of them is undetermined."""
    from learners.arrays.batch import make_batch
    from learners.em.accel import Packer
    from learners.em.uncertainty import parameter_uncertainty

    declared = variance_coordinates(model)
    if not declared:
        return model, None
    fixed = Packer(opts).fixed
    full = parameter_uncertainty(model, make_batch(logs), fixed=fixed)
    prefixes = tuple(f"effects.{name}.{p}" for name, params in declared.items() for p in params)
    coords = [k for k, n in enumerate(full.names) if n.startswith(prefixes)]
    record: dict[str, Any] = {"effects": {name: {p: {"maximum_likelihood": float(getattr(model.effect(name), p))}
                                                 for p in params} for name, params in declared.items()},
                              "step_se": {}, "length": 0.0, "taken": False, "why": ""}
    if len(coords) != len(prefixes):
        record["why"] = "a variance parameter is undetermined on these logs (no information)"
        return model, record
    x0 = model.pack(fixed)
    packed_at = np.flatnonzero(full.free)[coords]  # the coordinates' places in the packed vector
    gradient = adjustment_gradient(model, logs, fixed, packed_at, fixed | frozenset(VARIANCES) | frozenset(prefixes))
    step, in_se = newton_step(gradient, full.covariance[np.ix_(coords, coords)])
    record["step_se"] = {full.names[c]: round(float(z), 3) for c, z in zip(coords, in_se)}
    if np.max(np.abs(in_se)) > MAX_STEP_SE:
        record["why"] = f"the step is {np.max(np.abs(in_se)):.1f} standard errors long (not local: above {MAX_STEP_SE:g})"
        return model, record
    delta = np.zeros_like(x0)
    delta[packed_at] = step
    drop, why = held_drop(model, model.unpack(x0 + delta, fixed), logs, opts, tuple(declared))
    if why:
        record["why"] = why
        return model, record
    record["length"] = step_length(float(-0.5 * gradient @ step), drop)
    stepped = model.unpack(x0 + record["length"] * delta, fixed)
    for name, params in declared.items():
        for p in params:
            record["effects"][name][p]["restricted"] = float(getattr(stepped.effect(name), p))
    record["taken"] = True
    return stepped, record


def adjustment_gradient(model: Model, logs: list[Trajectory], fixed: frozenset[str], packed_at: np.ndarray,
                        theta_fixed: frozenset[str]) -> np.ndarray:
    """d log det I_theta / d x at ``model`` for each coordinate ``packed_at`` of ``model.pack(fixed)``, by central
    differences of ``DIFFERENCE_STEP`` with theta (every coordinate but ``theta_fixed``) held at the fit."""
    x0 = model.pack(fixed)
    gradient = np.empty(len(packed_at))
    for k, at in enumerate(packed_at):
        ends = []
        for sign in (-1.0, 1.0):
            x = x0.copy()
            x[at] += sign * DIFFERENCE_STEP
            ends.append(log_information(model.unpack(x, fixed), logs, theta_fixed))
        gradient[k] = (ends[1] - ends[0]) / (2.0 * DIFFERENCE_STEP)
    return gradient


def held_drop(model: Model, end: Model, logs: list[Trajectory], opts: EMOptions,
              effects: tuple[str, ...]) -> tuple[float, str]:
    """(the likelihood's fall from the fit ``model`` to the fit from ``end`` with ``effects`` held there, the rest
    refitted (nats), "" or why there is none): the effects' parameters must all be variance ones (``frozen`` holds
    a whole effect). A failed fit or a non-finite likelihood gives no fall."""
    from learners.discrepancy.fitting import train_loglik
    from learners.em.learner import EMLearner

    held = replace(opts, frozen=tuple(opts.frozen) + effects, uncertainty=False, polish=False, restricted_noise=False)
    try:
        fit = EMLearner(held, check_field=False).fit(logs, init=end).params
        drop = train_loglik(model, logs) - train_loglik(fit, logs)
    except (FloatingPointError, np.linalg.LinAlgError, ValueError) as err:
        return math.nan, f"the fit held at the step's end failed ({err})"
    return drop, "" if math.isfinite(drop) else "the fit held at the step's end has no finite likelihood"

