"""The statistics a calibrated simulator is compared on: one number each, computed the same way on the
measured logs and on logs simulated from the fitted model (``experiments.calibrated``), so that the
simulated spread calibrates every one of them (a parametric-bootstrap, posterior predictive check).

Four kinds:

- fit consistency (:func:`learners.discrepancy.score.score`): the held-out gap (nats per sighting),
  the mean normalized innovation squared (NIS), its share outside the chi-square 95% band, its median (the
  innovations' core: a noise with heavier tails than one Gaussian's has a sharper core, which the mean and the share
  outside the band can miss: ``heavy_tailed_noise``), the whiteness of the size innovations and of the bearing
  innovations (lag-1 autocorrelation over one landmark's consecutive sightings: ``landmark_bias``,
  ``landmark_bearing_bias``);
- residual signatures (:func:`learners.discrepancy.signatures.signatures`): the strength
  (-log10 p)^(1/3) of each (residual, variable) dependence. Their p-values assume independent
  residuals and are optimistic; the simulated spread of the strength is the honest reference. The
  check's threshold takes each statistic's spread over the replicas as Gaussian; -log10 p is a
  chi-square-like, right-skewed quantity, and its cube root is close to Gaussian (Wilson & Hilferty 1931).
  Measured (30 models of effect-free 5-minute logs, `aibo`, `paper-sim` and `WheeledRobot-v0`, 40 replicas each,
  each replica in turn checked against 8 others; docs/results.md, "The calibrated check on effect-free logs"):
  the signatures' median skewness over the replicas 0.08-0.14 with the cube root, 0.45-0.55 with the square root
  used before, and the check's family false alarms with 8 replicas 4.9-5.2% against 7.3-9.1% (with 4 to 24 replicas
  4.3-5.2%, where the square root's grow to 8.9-12.4%);
- score statistics (:mod:`learners.discrepancy.score_tests`): how strongly the log pulls the model towards a generic
  alternative (a speed that changes over the log), where a signature of the smoothed motion is attenuated, and the
  likelihood's gain from bearing states per landmark of a fixed size, where the heading takes up such biases;
- the data alone: sightings per frame, size quantiles (px or mm), spread of the bearings (rad).
"""

from __future__ import annotations

import math

import numpy as np

from aibo_core.trajectory import Trajectory
from learners.model.model import Model

from .score import score
from .score_tests import BEARING_BIAS, SPEED_TREND, score_statistics
from .signatures import signatures

MAX_STRENGTH = 300.0  # -log10(p) cap (p below 1e-300 underflows)


def signature_key(residual: str, variable: str) -> str:
    return f"{residual} vs {variable}"


def strength(p_value: float) -> float:
    """(-log10 p)^(1/3) (module docstring), p floored at 10^-MAX_STRENGTH (below it p underflows)."""
    return min(max(-math.log10(max(p_value, 1e-300)), 0.0), MAX_STRENGTH) ** (1.0 / 3.0)  # p a rounding above 1: 0


def check_statistics(model: Model, logs: list[Trajectory]) -> dict[str, float]:
    """Every statistic (module docstring) of ``model`` on ``logs``, by name."""
    s = score(model, logs)
    out = {
        "held-out NLL per sighting (nats)": s.gap,
        "mean NIS": s.nis_mean,
        "share of NIS outside the 95% band": s.nis_outside,
        "median NIS": s.nis_median,
        "size-innovation autocorrelation (lag 1, per landmark)": s.whiteness,
        "bearing-innovation autocorrelation (lag 1, per landmark)": s.bearing_whiteness,
    }
    for sig in signatures(model, logs):
        out[signature_key(sig.residual, sig.variable) + " (strength)"] = strength(sig.p_value)
    out.update(score_statistics(model, logs))
    out.update(data_statistics(logs))
    return out


def data_statistics(logs: list[Trajectory]) -> dict[str, float]:
    """Statistics of the sightings alone (no model): how often and what the sensor reports."""
    size = np.concatenate([tr.sighting_value[:, 0] for tr in logs])
    bearing = np.concatenate([tr.sighting_value[:, 1] for tr in logs])
    frames = sum(tr.n_frames for tr in logs)
    q10, q50, q90 = np.quantile(size, [0.1, 0.5, 0.9]) if len(size) else (np.nan,) * 3
    return {
        "sightings per frame": len(size) / max(frames, 1),
        "size, 10% quantile": float(q10),
        "size, median": float(q50),
        "size, 90% quantile": float(q90),
        "bearing spread (rad)": float(np.std(bearing)) if len(bearing) else np.nan,
    }


#: What each statistic of the sightings alone (``data_statistics``) says about the log, for ``plain_reading``: (the
#: sentence's subject and verb, its two directions).
_DATA_READING = {
    "sightings per frame": ("the log's robot reports", "more sightings per frame", "fewer sightings per frame"),
    "size, 10% quantile": ("the log's sizes run", "larger at their 10% quantile", "smaller at their 10% quantile"),
    "size, median": ("the log's sizes run", "larger at their median", "smaller at their median"),
    "size, 90% quantile": ("the log's sizes run", "larger at their 90% quantile", "smaller at their 90% quantile"),
    "bearing spread (rad)": ("the log's bearings spread", "wider", "narrower"),
}

#: Why a statistic of the sightings alone can differ without a sensor effect: the check replays the measured commands
#: open loop, and a robot that steered on its own pose went elsewhere than its replays do (docs/results.md, "The
#: calibrated check on effect-free logs": on effect-free simulated logs such statistics were the ones left once each
#: replica was fitted as the measured log was).
_WHERE_IT_WENT = ("what the sensor reports (a camera's angle or size scaled, a detection that reaches other distances or "
                  "angles) or where the robot went: a statistic of the sightings alone, and the replays of the measured "
                  "commands go elsewhere than a robot that steered on its own pose")

#: The other cause of bearing errors that persist per landmark: a sensor away from the robot's origin, taken to sit at it,
#: errs in bearing by about its offset x sin(bearing) / distance while a landmark is in view (an independent generator's
#: logs with a camera 0.25 m ahead: "bearing-innovation autocorrelation" z +8.9 after the named effects, none with it at
#: the origin; docs/real-logs.md, "A sensor away from the robot's origin").
_SENSOR_MOUNT = ("; or a sensor away from the robot's origin taken to sit at it: the importers' --sensor-pose moves its "
                 "sightings there")

#: What a residual signature's variable says about the log, for ``plain_reading``.
_VARIABLE_READING = {
    "landmark": "differ from landmark to landmark (per-landmark errors: a landmark's mapped position or size, or how "
                "the camera sees it)",
    "distance": "change with the distance to the landmark",
    "world heading": "change with the robot's heading in the world (a floor, a slope or a wall that favours a "
                     "direction)",
    "elapsed time": "drift over the log",
    "position in the image": "change across the image",  # before "position": the first key a variable starts with
    "position": "change across the field",
    "turn rate": "change with the turn rate (timing: a sensor's time offset or the motion's lag)",
    "commanded turn rate": "change with how fast the robot is commanded to turn (a motion noise that grows with the "
                           "turn)",
    # a driver that steers on the robot's pose makes it too, with no timing error in the robot: simulated closed-loop
    # logs disagree at z +4.2 to +9.2 (16 of 16), and the MRCLAM robots' commands answer their motion within 0.1-0.2 s
    # (docs/results.md, "A driver that steers on its pose")
    "change of the commanded": "follow a change of the command otherwise than the model says (timing: the motion's "
                               "lag or its response time; or commands that answer the motion's own errors, a driver "
                               "that steered on the robot's pose, which replays of the measured commands cannot "
                               "make)",
}


def plain_reading(statistic: str, z: float) -> str:
    """A sentence on what the measured log does that its calibrated simulation does not, for a statistic of the
    check (``check_statistics``) whose z = (measured - simulated mean) / simulated sd disagrees."""
    more = z > 0
    if statistic == SPEED_TREND:
        return ("the log's robot moves " + ("faster" if more else "slower") + " later in the log, against what the "
                "model commands, than its simulation's" + ("" if more else " (a speed that fades: a draining battery, "
                                                                       "worn feet)"))
    if statistic == BEARING_BIAS:
        return ("the log's bearing errors of one landmark agree with each other over seconds "
                + ("more" if more else "less") + " than in its simulation"
                + (" (a bearing error per landmark that the heading takes up while the landmark is in view: "
                   f"landmark_bearing_bias{_SENSOR_MOUNT})" if more else ""))
    if " vs " in statistic:
        residual, variable = statistic.split(" vs ", 1)
        variable = variable.replace(" (strength)", "")
        what = next((text for key, text in _VARIABLE_READING.items() if variable.startswith(key)),
                    f"depend on {variable}")
        how = "more strongly than" if more else "less than"
        return f"the log's {residual} residuals {what} {how} in its simulation"
    if statistic.startswith("size-innovation autocorrelation"):
        return ("the log's size errors persist from one sighting of a landmark to the next "
                + ("more" if more else "less") + " than in its simulation"
                + (" (errors that persist and have no state in the model are taken up as motion noise: its robot "
                   "wanders more than the real one)" if more else ""))
    if statistic.startswith("bearing-innovation autocorrelation"):
        return ("the log's bearing errors persist from one sighting of a landmark to the next "
                + ("more" if more else "less") + " than in its simulation"
                + (f" (a bearing error per landmark that lasts seconds: landmark_bearing_bias{_SENSOR_MOUNT})"
                   if more else ""))
    if statistic.startswith("share of NIS outside"):
        return ("more" if more else "fewer") + (" of the log's sightings fall outside the model's 95% band than of its "
                                                "simulation's (below it: predicted more closely than the model's noise "
                                                "says; above it: errors the noise does not hold; the band has two "
                                                "sides)" if more else " of the log's sightings fall outside the "
                                                "model's 95% band than of its simulation's (the model's noise is too "
                                                "wide)")
    if statistic.startswith("median NIS"):
        return ("most of the log's sightings are predicted " + ("less" if more else "more") + " closely, against the "
                "model's noise, than its simulation's" + ("" if more else " (a sharper core than one Gaussian's: the "
                                                          "noise's shape, or errors that persist from one sighting to "
                                                          "the next; the row's 'where' says which)"))
    if statistic.startswith("mean NIS") or statistic.startswith("held-out NLL"):
        return ("the model predicts the log's sightings " + ("worse" if more else "better")
                + " than it predicts its own simulation's" + (" (an effect it lacks, or a fit short of its best: a "
                                                             "local optimum of EM; docs/results.md, 'The calibrated "
                                                             "check on effect-free logs')" if more else ""))
    if statistic in _DATA_READING:
        subject, up, down = _DATA_READING[statistic]
        return f"{subject} {up if more else down} than its simulation's ({_WHERE_IT_WENT})"
    return f"the log's {statistic} is {'higher' if more else 'lower'} than its simulation's"
