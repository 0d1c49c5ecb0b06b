"""Bearings of the other sign convention: a log whose bearings are clockwise (positive to the right) where aibo's are
counter-clockwise (positive to the left, REP 103), e.g. a camera's optical frame (x right) read as the body's.

A range sensor's fit does not fail on them: its ranges still place the robot, or nearly, and EM takes the bearings
for noise. Measured: ``WheeledRobot-v0``, 1,500 frames, seed 3, bearings negated: bearing noise 0.69 rad where the
log's is 0.02, smoothed pose 130 mm from the truth (21 as given); ``tests/_diffdrive.py``'s generator, 120 s, seed 3:
0.69 rad, 1,242 mm (the path lost); neither said a word. So a range sensor's fit whose bearings look wrong
(``suspect``: their noise above ``SUSPECT_SIGMA_RAD``, no camera's or lidar's, or the negated bearings fitting its
smoothed path as well as the given ones, ``sign_errors``) is made again on the logs with every bearing negated
(``sign_check``), and where that fit is ``MORE_LIKELY_NATS`` more likely the fit says so (``sign_warnings``). Height
cameras (``height_px``, the paper's) are not checked: their fits of negated bearings end in a wrong world, which
``aibo learn`` refuses.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from aibo_core.geometry import wrap
from aibo_core.trajectory import Trajectory
from learners.arrays.batch import Batch, make_batch
from learners.model.model import Model

#: Fewest sightings for a verdict.
MIN_SIGHTINGS = 50
#: A range sensor's bearing noise (rad) above which its bearings are suspect: 11 degrees, beyond any camera or lidar
#: (MRCLAM's camera: 0.02-0.03 rad).
SUSPECT_SIGMA_RAD = 0.2
#: The negated bearings' fit this much more likely (nats): the sign is the other.
MORE_LIKELY_NATS = 10.0


def sign_errors(batch: Batch, poses: np.ndarray) -> tuple[float, float] | None:
    """(median |bearing error| as given, the same with every bearing negated), rad, of ``batch``'s used sightings
    against their landmarks' map positions seen from ``poses`` (P, 3) [x mm, y mm, theta rad] (a fit's smoothed
    poses); None with fewer than ``MIN_SIGHTINGS``."""
    use = np.asarray(batch.used, bool)
    if np.count_nonzero(use) < MIN_SIGHTINGS:
        return None
    pose = poses[batch.sight_pose[use]]
    to = batch.landmarks[batch.sight_landmark[use]] - pose[:, :2]
    toward = np.arctan2(to[:, 1], to[:, 0]) - pose[:, 2]
    bearing = batch.sight_value[use, 1]
    return (float(np.median(np.abs(wrap(bearing - toward)))), float(np.median(np.abs(wrap(-bearing - toward)))))


def suspect(model: Model, batch: Batch, poses: np.ndarray) -> bool:
    """Whether a fit's bearings look like the other convention's (module docstring): with at least ``MIN_SIGHTINGS``,
    their noise above ``SUSPECT_SIGMA_RAD`` or the negated ones fitting ``poses`` as well (``sign_check`` asks it of a
    range sensor's fit only)."""
    errors = sign_errors(batch, poses)
    if errors is None:
        return False
    return model.sensor.sigma_bearing > SUSPECT_SIGMA_RAD or errors[1] <= errors[0]


def negated(logs: list[Trajectory]) -> list[Trajectory]:
    """``logs`` with every bearing negated (wrapped: -pi stays in [-pi, pi))."""
    return [replace(tr, sighting_value=np.stack([tr.sighting_value[:, 0], wrap(-tr.sighting_value[:, 1])], axis=1))
            for tr in logs]


def sign_check(logs: list[Trajectory], model: Model, options: Any) -> dict[str, Any] | None:
    """Where the fit ``model`` of ``logs`` is ``suspect`` (read from its smoothed poses): the fit made again, from
    the paper's start with ``options`` (an ``EMOptions``; no standard errors, no map repair), on the logs with their
    bearings negated, and both fits' log-likelihoods of their sightings (the E-step's, ungated; nats): {"loglik_given",
    "loglik_negated", "sigma_bearing_given", "sigma_bearing_negated"} (rad); None where not suspect."""
    from learners.em.estep import e_step
    from learners.em.learner import EMLearner

    if model.sensor.kind != "range_mm":
        return None
    batch = make_batch(logs)
    given = e_step(model, batch, "compiled")
    if not suspect(model, batch, given.mu_gamma):
        return None
    flipped = negated(logs)
    other = EMLearner(replace(options, uncertainty=False, map_repair=False), check_field=False).fit(flipped).params
    return {"loglik_given": float(given.loglik),
            "loglik_negated": float(e_step(other, make_batch(flipped), "compiled").loglik),
            "sigma_bearing_given": float(model.sensor.sigma_bearing),
            "sigma_bearing_negated": float(other.sensor.sigma_bearing)}


def sign_warnings(record: dict[str, Any] | None) -> list[str]:
    """One warning where the fit of the negated bearings (``sign_check``'s record) is ``MORE_LIKELY_NATS`` more
    likely, else []."""
    if record is None or record["loglik_negated"] < record["loglik_given"] + MORE_LIKELY_NATS:
        return []
    gain = record["loglik_negated"] - record["loglik_given"]
    return [f"the bearings fit with the opposite sign: the fit of the log(s) with every bearing negated is {gain:,.0f} "
            f"nats more likely (its bearing noise {record['sigma_bearing_negated']:.3f} rad, this fit's "
            f"{record['sigma_bearing_given']:.3f}): they are likely clockwise (positive to the right) where aibo's are "
            "counter-clockwise (positive to the left), e.g. a camera's optical frame (x right) read as the body's "
            "(aibo import bag --marker-frame); this fit took them for noise: negate them and fit again"]
