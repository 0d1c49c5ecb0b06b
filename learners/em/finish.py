"""Fisher scoring after EM: the maximum of the likelihood the learner reports, reached in a few steps.

Two measured facts (docs/results.md, "EM at the information bound") make EM's own stop a poor place to end:

- EM's fixed point is not the maximum of the EKF likelihood it reports. Its M-step maximizes the
  expected complete-data likelihood under the *linearized* smoother's posterior, which is not the
  derivative-consistent partner of the EKF's predictive likelihood. On 15-minute logs the maximum
  lies 5-10 nats above EM's fixed point, and its velocity errors are lower.
- EM creeps: the last ~250 of ~390 iterations gain ~4 nats along the weakly determined directions
  (the sensor curve's shape, sigma_height).

So EM runs until its gain per iteration is small (``EMOptions.switch_gain``), then Fisher scoring
finishes on the EKF log-likelihood itself (Jennrich & Sampson 1976; the EM-then-Newton hybrid of
Lange 1995 and Jamshidian & Jennrich 1997):

    x <- x + t I(x)^-1 g(x),

g the score and I the Fisher information of the innovations, both from ``learners.em.uncertainty``
with central differences (forward differences leave a noise floor of ~2-4 in the Newton decrement
that stalls the steps). After the first step, I^-1 is corrected by BFGS updates from the steps taken
(the observed curvature along some directions is several times the expected information's; pure
scoring then crawls at t ~ 0.06). The step length t comes from a quadratic fit along the line (the
slope at t = 0 is g^T H g, the value at t = 1 is one forward pass); a step is kept only when the
likelihood rises. It stops after a step gaining less than ``GAIN_TOL`` nats; the information is then
evaluated once more, so the standard errors are those of the returned model.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from learners.arrays.batch import Batch
from learners.em.uncertainty import Uncertainty, packed, parameter_uncertainty, unpacked
from learners.inference.kernels.estep import innovations_compiled
from learners.model.model import Model

#: Stop after a step that gained less than this (nats). Measured on a 15-minute log against 12 steps:
#: after steps gaining 15.5, 2.0 and 0.9 nats the velocities are within 0.18 standard errors of the
#: end (RMS 0.05), sigma_height within 0.18; the ~1.3 nats left lie along the sensor curve's shape.
GAIN_TOL = 1.0
#: At most this many scoring steps (each 2p forward passes, p the number of parameters).
MAX_STEPS = 4
#: The first information is taken by central differences (a negative step, ``learners.em.uncertainty``'s
#: convention); later ones by forward differences of FORWARD_REL standard deviations (1 / sqrt(I_kk) of
#: the previous evaluation) per coordinate: their truncation error, ~FORWARD_REL / 2 in the decrement,
#: is then as small as the central one's at half the passes.
CENTRAL_STEP = -1e-5
FORWARD_REL = 1e-3
#: Step lengths tried when the quadratic's step does not raise the likelihood.
BACKTRACK = (0.5, 0.25, 0.125, 0.0625)


@dataclass
class Finish:
    """The outcome of ``fisher_scoring``."""

    model: Model
    loglik: float
    uncertainty: Uncertainty | None  # at ``model`` (None when the last evaluation failed)
    record: dict[str, Any] = field(default_factory=dict)  # JSON-able: steps, gains, decrements
    passes: int = 0  # forward passes spent (2p per information evaluation, one per line-search point)
    seconds: float = 0.0  # wall time (kept out of the record: model files are reproducible)


def loglik_at(model: Model, batch: Batch) -> float:
    """The EKF log-likelihood of ``model`` on ``batch`` (its applied sightings): the one EM reports."""
    return innovations_compiled(model.lower(batch), batch)[0]


def _line(model: Model, batch: Batch, x: np.ndarray, d: np.ndarray, ll: float, slope: float,
          fixed: frozenset[str]) -> tuple[Model | None, float, float, int]:
    """The best point found along x + t d: (model or None when none beat ``ll``, its loglik, t, passes)."""
    tried: list[tuple[float, float, Model]] = []

    def value(t: float) -> float:
        try:
            m = unpacked(model, x + t * d, fixed)
            v = loglik_at(m, batch)
        except (FloatingPointError, np.linalg.LinAlgError, ValueError):
            return -np.inf
        tried.append((v, t, m))
        return v

    v1 = value(1.0)
    curvature = 2.0 * (ll + slope - v1)  # of the quadratic through (0, ll) with slope ``slope`` and (1, v1)
    if np.isfinite(v1) and curvature > 0:
        t = float(np.clip(slope / curvature, BACKTRACK[-1], 2.0))
        if abs(t - 1.0) > 0.1:
            value(t)
    for t in BACKTRACK:
        if max((v for v, _, _ in tried), default=-np.inf) > ll:
            break
        value(t)
    if not tried:  # every step length failed in the filter
        return None, -np.inf, 0.0, 0
    v, t, m = max(tried, key=lambda r: r[0])
    return (m if v > ll else None), v, t, len(tried)


def _steps(last: Uncertainty | None) -> float | np.ndarray:
    """Difference steps for the next information: central at first, then FORWARD_REL standard deviations."""
    if last is None:
        return CENTRAL_STEP
    steps = np.full(len(last.free), abs(CENTRAL_STEP))
    steps[last.free] = FORWARD_REL / np.sqrt(np.diag(last.information))
    return steps


def _bfgs(prev: tuple[np.ndarray, np.ndarray, np.ndarray] | None, x: np.ndarray, g: np.ndarray,
          unc: Uncertainty) -> np.ndarray:
    """The inverse curvature for the step from ``x``: I^-1 at the first step, then BFGS-updated with the
    last step's (s, y) (y = minus the score's change), kept when s^T y > 0; zero rows on undetermined
    coordinates."""
    H0 = np.zeros((len(x), len(x)))
    H0[np.ix_(unc.free, unc.free)] = unc.covariance
    if prev is None:
        return H0
    x0, g0, H = prev
    s, y = x - x0, g0 - g
    sy = float(s @ y)
    if sy <= 1e-12 * float(np.linalg.norm(s) * np.linalg.norm(y)):
        return H0
    rho = 1.0 / sy
    A = np.eye(len(x)) - rho * np.outer(s, y)
    # einsum, not BLAS: a threaded BLAS sums in an order that depends on the thread count, and the fit
    # must give the same numbers in a 1-thread worker as in the main process (experiments.executors)
    return np.einsum("ij,jk,lk->il", A, H, A, optimize=False) + rho * np.outer(s, s)


def fisher_scoring(model: Model, batch: Batch, fixed: frozenset[str] = frozenset(),
                   max_steps: int = MAX_STEPS, gain_tol: float = GAIN_TOL) -> Finish:
    """Scoring steps from ``model`` (EM's estimate) on ``batch`` (the fit's applied sightings) over every
    coordinate of ``learners.em.uncertainty.packed`` except ``fixed`` (module docstring). Stops after a
    step that gained less than ``gain_tol`` nats, when no step length raises the likelihood, or after
    ``max_steps``; the information is always evaluated at the returned model (its standard errors)."""
    t0 = time.perf_counter()
    batch = batch.holding_angle_noise(model.sensor.sigma_bearing)  # the image angle's noise held, as in EM
    ll = loglik_at(model, batch)
    out = Finish(model, ll, None, {"start_loglik": ll, "steps": []}, passes=1)
    prev: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # (x, g, H^-1) of the last step
    while True:
        try:
            unc = parameter_uncertainty(model, batch, fixed, step=_steps(out.uncertainty))
        except (FloatingPointError, np.linalg.LinAlgError, ValueError) as exc:
            out.record["error"] = f"scoring stopped: {str(exc)[:160]}"
            out.uncertainty = None
            break
        out.passes += unc.passes
        out.uncertainty = unc
        out.record["decrement"] = unc.newton_decrement
        steps = out.record["steps"]
        if steps and steps[-1]["gain_nats"] < gain_tol:
            out.record["stop"] = "converged"
            break
        if len(steps) == max_steps:
            out.record["stop"] = "max_steps"
            break
        x = packed(model, fixed)
        g = np.zeros(len(x))
        g[unc.free] = unc.score
        H = _bfgs(prev, x, g, unc)
        d = np.einsum("ij,j->i", H, g)  # not BLAS: see _bfgs
        new, v, t, passes = _line(model, batch, x, d, ll, float(np.einsum("i,i->", g, d)), fixed)
        out.passes += passes
        if new is None:  # no step length raised the likelihood: at the maximum within differencing noise
            steps.append({"decrement": unc.newton_decrement, "t": 0.0, "gain_nats": 0.0})
            out.record["stop"] = "no ascent"
            break
        steps.append({"decrement": unc.newton_decrement, "t": t, "gain_nats": v - ll})
        prev = (x, g, H)
        model, ll = new, v
        out.model, out.loglik = model, ll
    out.record["gain_nats"] = out.loglik - out.record["start_loglik"]
    out.record["converged"] = out.record.get("stop") in ("converged", "no ascent")
    out.seconds = time.perf_counter() - t0
    return out
