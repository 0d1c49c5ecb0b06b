"""What a log can determine: refuse a fit the data cannot support, and name what it leaves open.

Measured (issue 8, item 14): with 1 sighting EM wrote sigma_height 3.6e-15 px; with 5 sightings it
reported convergence with a curve 9 px off; with 30 it predicted -288 px at 1.3 m. A cubic sensor
curve and two noise sigmas need many sightings spread over distances, and a command never executed
says nothing about its velocity.
"""

from __future__ import annotations

import numpy as np

from learners.inference.batch import Batch
from learners.model.model import Model

#: Fewest sightings per sensor parameter (curve coefficients + 2 sigmas) for a fit to be attempted.
MIN_SIGHTINGS_PER_PARAMETER = 25
#: Smallest spread (mm) of smoothed distances over which a curve of degree > 1 is taken as determined.
MIN_DISTANCE_SPAN_MM = 500.0


class InsufficientDataError(ValueError):
    """The logs cannot determine the model (one line saying what is missing)."""


def check_support(batch: Batch, start: Model) -> list[str]:
    """Raise InsufficientDataError when the logs cannot support a fit; return the names of the
    parameters they leave undetermined (e.g. ``action_model.velocities[7]``: a command never executed)."""
    n_params = len(start.sensor.coef) + 2
    need = MIN_SIGHTINGS_PER_PARAMETER * n_params
    if batch.n_sightings < need:
        raise InsufficientDataError(
            f"the logs hold {batch.n_sightings} sightings; a sensor model of {n_params} parameters needs at least "
            f"{need} ({MIN_SIGHTINGS_PER_PARAMETER} per parameter): record a longer log")
    if batch.n_frames < 2:
        raise InsufficientDataError(f"the logs hold {batch.n_frames} frame(s): nothing to learn a motion from")
    commands = batch.actions if batch.actions is not None else batch.controls
    determined = start.action.determined(commands)
    if not determined.any():
        raise InsufficientDataError("the commands in the logs determine none of the action model's weights")
    label = "velocities" if start.action.discrete else "weights"
    return [f"action_model.{label}[{i}]" for i in np.flatnonzero(~determined)]


def curve_warnings(model: Model) -> list[str]:
    """Warnings about a learned sensor curve: a narrow distance range, or a non-positive size in it."""
    lo, hi = model.sensor.distance_range_mm
    out = []
    if hi - lo < MIN_DISTANCE_SPAN_MM and len(model.sensor.coef) > 2:
        out.append(f"the sightings cover distances {lo:.0f}-{hi:.0f} mm only: the sensor curve is not determined "
                   "outside that range")
    d = np.linspace(lo, hi, 50)
    if np.any(model.sensor.mean(d) <= 0):
        out.append(f"the learned sensor curve predicts non-positive sizes within {lo:.0f}-{hi:.0f} mm: the data "
                   "do not determine it")
    return out
