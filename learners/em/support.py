"""What a log can determine: refuse a fit the data cannot support, and name what it leaves open.

Measured: with 1 sighting EM wrote sigma_height 3.6e-15 px; with 5 sightings it
reported convergence with a curve 9 px off; with 30 it predicted -288 px at 1.3 m. A cubic sensor
curve and two noise sigmas need many sightings spread over distances, and a command never executed
says nothing about its velocity.

A fit can also be determined and still wrong: on MRCLAM robot 4 (2 sightings/s, errors correlated
from sighting to sighting) EM reaches a world whose forward speed depends on the turn direction
(-335 mm/s per rad/s of omega, where Vicon says +3), from the paper's start, from the true start
pose and from the commands' face value alike. No truth is needed to see it: the learned velocities
depart from the commands' face value by 71% of the commanded speed range (7-24% on robots 1, 2, 3
and 5). ``face_value_warnings`` says so when the controls are velocities with known units.
With the range curve held at range = distance (``EMOptions.range_curve``) robot 4 comes nearer (-155 mm/s per
rad/s, a 35% departure, under the 40% bar) and is still wrong; its forward speed depends on the turn direction, which
a wheeled robot's hardly does: ``mirror_warnings`` says so (``mirror_asymmetry``: 0.28 of the commanded speed range
on robot 4, 0.036-0.087 on the others, 0.001-0.010 for fits to Vicon).

A fit can also sit at the likelihood's maximum and still be far off, because the log hardly determines some
command: on 5-minute logs (each command held once or twice) two commands held once can trade displacement
along a flat ridge of the likelihood. Of the first 80 paper-sim 5-minute logs of seed 600, three had vx or vy
errors above 5% of the range; started at the true velocities, EM reached a point only 0.5-2.5 nats more likely
and within 1 standard error of the fit (no missed optimum), and the worst command's standard error was 5.7%,
10.2% and 32.5% of the range. ``weak_command_warnings`` names commands whose standard error exceeds
WEAK_SE_FRACTION of the range.

A command table's fit can also end in a world turned or mirrored against the robot's where the map has two landmarks'
ids swapped: the paper's four beacons allow a world where the bearings fit the swapped map to 0.003 rad (an `aibo`
log of 1,500 frames, seed 2, beacons 0 and 1 swapped), the sizes taking the difference as noise (sigma_height 54% off)
and the walk velocities turned by 155 degrees. ``walk_warnings`` says so where the learned (vx, vy) do not follow the
attempted ones (``walk_agreement``; measured in ``MIN_WALK_AGREEMENT``'s comment).
"""

from __future__ import annotations

import numpy as np

from aibo_core.trajectory import VELOCITY_CONTROLS, Trajectory
from learners.arrays.batch import Batch
from learners.model.model import Model

#: Fewest sightings per sensor parameter (curve coefficients + 2 sigmas) for a fit to be attempted.
MIN_SIGHTINGS_PER_PARAMETER = 25
#: A command whose velocity standard error exceeds this fraction of the learned table's range (per component)
#: is named as weakly determined. At 15 minutes the largest is ~3%; at 5 minutes 7% in the median log.
WEAK_SE_FRACTION = 0.10
#: Smallest spread (mm) of smoothed distances over which a curve of degree > 1 is taken as determined.
MIN_DISTANCE_SPAN_MM = 500.0
#: Largest RMS departure of the learned forward speed (turn rate) from the commanded v (omega), as a
#: fraction of the commanded range (1st-99th percentile), before the fit is called doubtful. Measured
#: on MRCLAM: 0.07-0.24 (turn 0.02-0.06) on four robots whose fit beats the commands, 0.71 on robot 4.
MAX_FACE_VALUE_DEPARTURE = 0.4
#: Largest RMS half-difference of the learned forward speed between a command (v, omega) and its mirror (v, -omega),
#: as a fraction of the commanded speed range, before the fit is called doubtful. A wheeled robot's forward speed
#: hardly depends on the turn direction (a wheel-radius mismatch of 2% on a 0.25 m axle: ~3 mm/s per rad/s).
#: Measured on the five MRCLAM robots (docs/results.md, "Why robots 3 and 4 ended in wrong worlds"): Vicon fits
#: 0.001-0.010, learned 0.036-0.087 on robots 1, 2, 3, 5 and 0.28 on robot 4 (0.54 before the range curve was held).
MAX_MIRROR_ASYMMETRY = 0.2
#: Least R^2 of the learned walk velocities on a turn and scale of the attempted ones (``walk_agreement``) before the
#: fit is called turned or mirrored. Measured on blind simulated logs (2026-12-02; seeds 0-5, both presets, 1,500 and
#: 9,000 frames): the 21 fits that finished, R^2 0.88-0.97, turned -5.4 to +2.2 degrees; with beacons 0 and 1 exchanged
#: in the map, 12 of 20 refused as a wrong world and the other 8 at R^2 -0.06 to 0.66, turned 1-176 degrees (each one
#: below 0.5 or beyond 20 degrees). Out of sample, seeds 100-129 (60 logs of 1,500 frames): no warning.
MIN_WALK_AGREEMENT = 0.5
#: Largest turn (rad) between the attempted and the learned walk velocities (``walk_agreement``) before the fit is
#: called turned: 20 degrees. Measured with ``MIN_WALK_AGREEMENT``.
MAX_WALK_TURN_RAD = np.radians(20.0)


class InsufficientDataError(ValueError):
    """The logs cannot determine the model (one line saying what is missing); ``field``: the log field
    that lacks it (``sighting_frame``, ``actions``, ``controls``), so a caller that knows the files can
    name them. Pickles with its field (fits run in worker processes)."""

    def __init__(self, message: str, field: str = ""):
        super().__init__(message, field)
        self.field = field

    def __str__(self) -> str:
        return str(self.args[0])


class StartModelError(ValueError):
    """The start model (``--init``) does not fit the logs: ``model_field`` (of the model file) disagrees
    with ``field`` (of the log). Pickles with its fields."""

    def __init__(self, message: str, model_field: str = "", field: str = ""):
        super().__init__(message, model_field, field)
        self.model_field, self.field = model_field, field

    def __str__(self) -> str:
        return str(self.args[0])


def check_support(batch: Batch, start: Model) -> list[str]:
    """Raise InsufficientDataError when the logs cannot support a fit; return the names of the
    parameters they leave undetermined (e.g. ``action_model.velocities[7]``: a command never executed;
    ``effects.beacon_height_scale.scale[3]``: a landmark never sighted, ``EffectModel.undetermined``)."""
    n_params = len(start.sensor.coef) + 2
    need = MIN_SIGHTINGS_PER_PARAMETER * n_params
    commands_field = "actions" if batch.actions is not None else "controls"
    if batch.n_sightings < need:
        raise InsufficientDataError(
            f"the logs hold {batch.n_sightings} sightings; a sensor model of {n_params} parameters needs at least "
            f"{need} ({MIN_SIGHTINGS_PER_PARAMETER} per parameter): record a longer log", "sighting_frame")
    if batch.n_frames < 2:
        raise InsufficientDataError(f"the logs hold {batch.n_frames} frame(s): nothing to learn a motion from",
                                    commands_field)
    commands = batch.actions if batch.actions is not None else batch.controls
    determined = start.action.determined(commands)
    if not determined.any():
        raise InsufficientDataError("the commands in the logs determine none of the action model's weights",
                                    commands_field)
    label = "velocities" if start.action.discrete else "weights"
    return [f"action_model.{label}[{i}]" for i in np.flatnonzero(~determined)] + [
        f"effects.{e.name}.{entry}" for e in start.effects for entry in e.undetermined(batch)]


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


def face_value_departure(model: Model, controls: np.ndarray) -> tuple[float, float] | None:
    """(forward, turn) RMS of learned velocity minus commanded velocity over ``controls`` (N, 2), each as
    a fraction of the commanded range (1st-99th percentile); None unless the controls are velocities
    (``VELOCITY_CONTROLS``)."""
    a = model.action
    if a.discrete or tuple(a.control_names) != VELOCITY_CONTROLS or controls is None or not len(controls):
        return None
    c = np.asarray(controls, dtype=float)
    diff = a.velocity(c)[:, [0, 2]] - c
    span = np.diff(np.percentile(c, [1, 99], axis=0), axis=0)[0]
    rms = np.sqrt(np.mean(diff**2, axis=0))
    out = np.where(span > 0, rms / np.where(span > 0, span, 1.0), 0.0)
    return float(out[0]), float(out[1])


def face_value_warnings(model: Model, controls: np.ndarray | None) -> list[str]:
    """A warning when the learned velocities depart from the commands' face value by more than
    ``MAX_FACE_VALUE_DEPARTURE`` of the commanded range: the fit may have found a wrong world (module
    docstring)."""
    dep = face_value_departure(model, controls)
    if dep is None or max(dep) <= MAX_FACE_VALUE_DEPARTURE:
        return []
    return [f"the learned velocities depart from the commands' face value by {dep[0]:.0%} (forward) and {dep[1]:.0%} "
            f"(turn) of the commanded range (RMS over the log; above {MAX_FACE_VALUE_DEPARTURE:.0%}): this fit may "
            "be wrong (a local optimum, or sensor errors the model takes as motion); check it against ground "
            "truth or a longer log before using it"]


def mirror_asymmetry(model: Model, controls: np.ndarray | None) -> float | None:
    """RMS over the log's commands of (vx(v, omega) - vx(v, -omega)) / 2, as a fraction of the commanded speed
    range (1st-99th percentile); None unless the controls are velocities (``VELOCITY_CONTROLS``)."""
    a = model.action
    if a.discrete or tuple(a.control_names) != VELOCITY_CONTROLS or controls is None or not len(controls):
        return None
    c = np.asarray(controls, dtype=float)
    span = float(np.diff(np.percentile(c[:, 0], [1, 99]))[0])
    if span <= 0:
        return None
    half = 0.5 * (a.velocity(c)[:, 0] - a.velocity(c * np.array([1.0, -1.0]))[:, 0])
    return float(np.sqrt(np.mean(half**2)) / span)


def mirror_warnings(model: Model, controls: np.ndarray | None) -> list[str]:
    """A warning when the learned forward speed depends on the turn direction by more than MAX_MIRROR_ASYMMETRY of
    the commanded speed range (``mirror_asymmetry``): a wheeled robot's does not; the fit may be in a wrong world."""
    asym = mirror_asymmetry(model, controls)
    if asym is None or asym <= MAX_MIRROR_ASYMMETRY:
        return []
    return [f"the learned forward speed depends on the turn direction by {asym:.0%} of the commanded speed range (RMS "
            f"half-difference between omega and -omega; above {MAX_MIRROR_ASYMMETRY:.0%}; a wheeled robot's hardly "
            "does): this fit may be in a wrong world; check it against ground truth or a longer log before using it"]


def walk_agreement(model: Model, logs: list[Trajectory]) -> tuple[float, float] | None:
    """How the learned walk velocities (vx, vy) of a command table follow the commands' attempted ones: the best turn
    and scale of the attempted (vx, vy) onto the learned, each command weighted by its frames in ``logs`` (one complex
    least-squares fit, learned ~ s x attempted), as (R^2, the turn, rad); None for velocity commands, or fewer than
    three commands used."""
    if not model.action.discrete or any(not tr.discrete for tr in logs):
        return None
    counts = np.bincount(np.concatenate([tr.actions for tr in logs]), minlength=len(model.action.velocities))
    used = counts > 0
    if np.count_nonzero(used) < 3:
        return None
    w = counts[used].astype(float)
    att = np.asarray(logs[0].attempted, float)[used]
    v = model.action.velocities[used]
    a, learned = att[:, 0] + 1j * att[:, 1], v[:, 0] + 1j * v[:, 1]
    total = np.sum(w * np.abs(learned - np.average(learned, weights=w)) ** 2)
    if total <= 0 or np.sum(w * np.abs(a) ** 2) <= 0:
        return None
    s = np.sum(w * np.conj(a) * learned) / np.sum(w * np.abs(a) ** 2)
    return float(1.0 - np.sum(w * np.abs(learned - s * a) ** 2) / total), float(np.angle(s))


def walk_warnings(model: Model, logs: list[Trajectory]) -> list[str]:
    """A warning where the learned walk velocities do not follow the commands' attempted ones (``walk_agreement``:
    R^2 below ``MIN_WALK_AGREEMENT``, or turned by more than ``MAX_WALK_TURN_RAD``): the fit's world is turned or
    mirrored against the robot's."""
    agreement = walk_agreement(model, logs)
    if agreement is None or (agreement[0] >= MIN_WALK_AGREEMENT and abs(agreement[1]) <= MAX_WALK_TURN_RAD):
        return []
    r2, turn = agreement
    return [f"the learned walk velocities do not follow the commands' attempted ones (the best turn and scale of the "
            f"attempted (vx, vy) explains R^2 {r2:.2f} of them, turned by {np.degrees(turn):+.0f} degrees; where the fit "
            f"found the robot's world, R^2 {MIN_WALK_AGREEMENT:.1f} or more within {np.degrees(MAX_WALK_TURN_RAD):.0f} "
            "degrees): the fit's world may be turned or mirrored against the robot's (two landmarks' ids swapped in "
            "the map, or bearings of the other sign); check the map against a few sightings"]


def weak_command_warnings(model: Model, se_velocities: np.ndarray | None) -> list[str]:
    """One line naming the commands (of a command table) whose standard error (``se_velocities``, (A, 3), NaN or
    None where undetermined) exceeds WEAK_SE_FRACTION of the learned velocities' range, per component: the
    data hardly determine them, and their error may be several standard errors (the likelihood is far from
    quadratic for a command held once)."""
    if se_velocities is None or not model.action.discrete:
        return []
    se = np.asarray(se_velocities, dtype=float)
    v = model.action.velocities
    span = v.max(axis=0) - v.min(axis=0)
    rel = np.nan_to_num(se / np.where(span > 0, span, np.inf), nan=0.0).max(axis=1)  # a flat component: never weak
    weak = np.flatnonzero(rel > WEAK_SE_FRACTION)
    if len(weak) == 0:
        return []
    worst = int(weak[np.argmax(rel[weak])])
    units = ("mm/s", "mm/s", "rad/s")
    detail = ", ".join(f"{name} +-{se[worst, k]:.3g} {units[k]}" for k, name in enumerate(("vx", "vy", "vtheta")))
    return [f"weakly determined: command(s) {', '.join(str(int(a)) for a in weak)} have standard errors above "
            f"{WEAK_SE_FRACTION:.0%} of the learned range (command {worst}: {detail}); their velocities may be off by "
            "several times that: a longer log, with more holds of them, would pin them down"]


#: Lag-1 autocorrelation of the normalized size innovations above which a model without bias states is told that its
#: size errors drift per landmark (``learners.em.whiteness``), and at least 3 standard errors (3 / sqrt(pairs))
#: above 0. Measured on fits without bias states: MRCLAM robots 0.71-0.89; simulated 5-minute logs (seed 21) with
#: ``landmark_bias`` sigma_rel 0.1 / 0.15 / 0.2 and tau_s 8 / 20 / 20 s: 0.19 / 0.21 / 0.24 (the filter follows the
#: heights with the pose and takes part of the bias out of the innovations); without a bias -0.03 to 0.003, and
#: 0.07 with per-beacon height factors of 4-8% (no drift, a constant per landmark).
CORRELATED_SIZE_LAG1 = 0.15
MIN_PAIRS = 30  # fewer pairs of consecutive sightings of one landmark: no verdict
#: the end of that warning: what to run (``aibo diagnose`` replaces it with what its search found)
TESTS_BIAS = "`aibo diagnose` on the log(s) tests landmark_bias (bias states)"


def correlated_size_warnings(model: Model, batch: Batch) -> list[str]:
    """A warning when the size (height or range) errors of one landmark correlate from sighting to sighting and the
    model holds no bias states: the fit then absorbs the drifting errors as motion noise and pose error, and
    ``aibo diagnose`` tests ``landmark_bias`` (module docstring of ``learners.model.landmark_bias``)."""
    from learners.em.whiteness import size_error_lag1

    if model.effect("landmark_bias") is not None:
        return []
    r, n = size_error_lag1(model, batch)
    if n < MIN_PAIRS or not r > max(CORRELATED_SIZE_LAG1, 3.0 / np.sqrt(n)):
        return []
    return [f"the size errors of one landmark correlate from sighting to sighting (lag-1 autocorrelation {r:.2f} over "
            f"{n} pairs; white errors give about 0): they drift per landmark, which this model does not hold; "
            + TESTS_BIAS]
