"""Score statistics: how strongly the log pulls a fitted model towards a generic alternative, from one E-step (and,
for per-landmark bearing biases, the alternative's likelihood gain at a fixed size: below).

A binned signature (:mod:`learners.discrepancy.signatures`) reads a drift off the smoothed motion residuals, and those
are attenuated where the sightings say little about each frame's motion: under a model without a trend the smoother
keeps each frame's displacement near the model's. A 2% per minute speed fade (``velocity_fade`` 0.02/min, 10-minute
``aibo`` log, seed 4) moves the true speed 7% below the model's in the last two minutes; the smoothed displacement
moves 1%, and "forward motion vs elapsed time" stayed within its replicas' spread (strength 0.68 against 0.42-1.5).

The score of the alternative (the gradient of the log-likelihood at the fitted model; by Fisher's identity the complete-data
score's expectation under the smoothed path) weights every frame by what the alternative would change, which is the
locally most powerful test of it (Rao's score test). For a factor (1 + c phi_i) on every component of frame i's
displacement p_i (mm, mm, rad), with W_i the frame's motion information (``Lowered.frame_cov``'s inverse) and mu*_i
the posterior mean displacement (``learners.arrays.displacement``):

    b_i = p_i' W_i (mu*_i - p_i),   a_i = p_i' W_i p_i,   S = sum_i b_i phi~_i / sqrt(sum_i a_i phi~_i^2),

phi~ the covariate centred within each discrete command in force (after a lag; weights a_i; continuous commands: over
all frames), so the commands' own velocities, which the fit sets, take none of it. S is the score over its
complete-data standard error, about N(0, 1) where the model is right; the calibrated check compares it with its
replicas' spread, the honest reference (the complete-data information overstates the observed one). On the log above:
S = -9.0 against replicas between -0.6 and +0.7 (z -20); on 5 minutes -2.1 (z -2.6); effect-free, 5 minutes: +0.6
(z +0.8).

A bearing bias of each landmark's own that changes over seconds (``landmark_bearing_bias``) hides from the filter's
innovations and from the smoothed residuals' signatures: while the robot sights one landmark the filter turns its
heading to that landmark's bias. The statistic for it is the likelihood's gain from the alternative itself at a fixed
size: the model with a bearing state per landmark of ``BEARING_STATE_SIGMA`` times its bearing noise and a correlation
time of ``BEARING_TAU_S`` added (nothing refitted; one forward pass each), over the model (nats). Where the model is
right the gain is near 0 or below (effect-free 5-minute ``aibo`` logs, seeds 4-6: -3.1, -1.2, -2.0); with biases of
0.02 rad at 20 s, +21, +13, +31 (2026-11-30). The variance component's score test (each landmark's smoothed bearing
residuals over their noise variance, paired with an exponential kernel of their time apart: the derivative in sigma^2
at 0) moved by +0.5 to +1.3 against the replicas' sd of 0.3-0.6 there, z 0.9-2.1: at the null's boundary the
score is weak. ``BEARING_TAU_S``: the whole-log fits of the five MRCLAM robots put the bias's correlation time at 11-152
s (two at 464 and 653 s, fixed offsets in effect); ``BEARING_STATE_SIGMA``: half the noise, where the MRCLAM scans with
learn's model held found their best rows (0.3-0.6 of the bearing noise: ``landmark_bearing_bias.WARM_GRID``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from learners.arrays.batch import Batch, make_batch
from learners.arrays.displacement import displacement_beliefs
from learners.arrays.lowered import Lowered
from learners.em.estep import e_step
from learners.em.options import DEFAULT_GATE
from learners.inference.kernels.estep import innovations_compiled
from learners.model.landmark_bearing_bias import LandmarkBearingBias

if TYPE_CHECKING:
    from aibo_core.trajectory import Trajectory
    from learners.model.model import Model

#: The check statistic's name: the score of a speed factor linear in the elapsed time (module docstring).
SPEED_TREND = "motion scale vs elapsed time (score)"
#: s: the correlation time of the bearing states whose likelihood gain is a statistic (module docstring)
BEARING_TAU_S = 30.0
#: their stationary sd as a multiple of the model's bearing noise sd (module docstring)
BEARING_STATE_SIGMA = 0.5
#: The check statistic's name: that gain (module docstring).
BEARING_BIAS = f"gain of bearing states per landmark ({BEARING_TAU_S:g} s, nats)"


def factor_score(p: np.ndarray, w_p: np.ndarray, mu_star: np.ndarray, phi: np.ndarray,
                 commands: np.ndarray | None) -> tuple[float, float]:
    """(S, c1): the normalized score S of the factor (1 + c phi_i) on the displacements ``p`` (N, 3) and the one-step
    estimate c1 = sum b phi~ / sum a phi~^2 (module docstring; attenuated where the sightings say little about the
    motion: a direction, not a size). ``w_p`` (N, 3): W_i p_i; ``mu_star`` (N, 3) the posterior mean displacements;
    ``phi`` (N,) the covariate; ``commands`` (N,) discrete command indices or None. (0, 0) when the covariate is
    constant within every command."""
    a = np.einsum("ij,ij->i", w_p, p)
    b = np.einsum("ij,ij->i", w_p, mu_star - p)
    groups = np.zeros(len(p), dtype=int) if commands is None else np.asarray(commands, dtype=int)
    weight = np.bincount(groups, weights=a)
    centre = np.bincount(groups, weights=a * phi) / np.where(weight > 0, weight, 1.0)
    centred = phi - centre[groups]
    info = float(np.sum(a * centred * centred))
    if not info > 0:
        return 0.0, 0.0
    score = float(np.sum(b * centred))
    return score / np.sqrt(info), score / info


def speed_trend_score(lo: Lowered, batch: Batch, mu_star: np.ndarray, commands: np.ndarray | None) -> float:
    """S (module docstring) of a speed factor linear in the elapsed time (min) on ``batch``'s frames, the model lowered
    as ``lo``; ``mu_star`` (N, 3) its posterior mean displacements; ``commands`` (N,) the discrete commands in force
    (after a lag) or None. Negative: the log moves slower later than the model says."""
    return factor_score(lo.disp, lo.information(lo.disp), mu_star, batch.frame_time / 60.0, commands)[0]


def bearing_states_gain(model: "Model", batch: Batch, lo: Lowered) -> float:
    """The forward filter's log-likelihood (nats) of ``batch`` under ``model`` with per-landmark bearing states of
    ``BEARING_STATE_SIGMA`` times its bearing noise at ``BEARING_TAU_S`` (replacing its own, if it has them) minus
    under ``model`` (``lo`` its lowering): positive where the log's bearings err per landmark over seconds."""
    states = LandmarkBearingBias(sigma_rad=BEARING_STATE_SIGMA * float(lo.sigma_bearing), tau_s=BEARING_TAU_S)
    return innovations_compiled(model.with_effect(states).lower(batch), batch)[0] - innovations_compiled(lo, batch)[0]


def score_statistics(model: "Model", logs: list["Trajectory"]) -> dict[str, float]:
    """Every score statistic of ``model`` on ``logs``, by name (the calibrated check's: ``statistics.check_statistics``),
    from one E-step with the sightings beyond the default gate set aside, as the signatures have it (with bias states,
    the augmented E-step's displacement beliefs), and the bearing states' gain from two forward passes (14 ms on a
    15-minute MRCLAM log, 4% of the check's statistics)."""
    batch = make_batch(logs)
    lo = model.lower(batch)
    post = e_step(model, batch, "compiled", DEFAULT_GATE, lo=lo)
    mu_star, _ = displacement_beliefs(lo, batch, post)
    commands = model.effective_commands(batch)[0] if model.action.discrete else None
    return {SPEED_TREND: speed_trend_score(lo, batch, mu_star, commands),
            BEARING_BIAS: bearing_states_gain(model, batch, lo)}
