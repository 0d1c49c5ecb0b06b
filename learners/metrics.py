"""Errors of learned models against a simulated log's ground truth (``meta["truth"]``).

The figures are those of the paper's section IV-B: RMS velocity errors over the actions
(absolute and as a fraction of each component's range over the 40 true velocities; for continuous
commands, over every frame's command of the logs, NaN for a component that never varies),
relative errors of the two noise sigmas, and the sensor model's RMS error over the range
of observed distances.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from aibo_core.features import features
from learners.arrays.lowered import curve
from learners.model.model import Model
from learners.model.sensor import BASES, SensorModel

#: The paper's simulated results (section IV-B), for side-by-side tables.
PAPER_SIM = {
    "vx_rms": 23.06, "vy_rms": 18.34, "vtheta_rms": 0.086,
    "vx_rel": 0.032, "vy_rel": 0.022, "vtheta_rel": 0.027,
    "sigma_height_rel": 0.020, "sigma_angle_rel": 0.053,
    "sensor_rms_px": 0.35, "sensor_rms_start_px": 12.71, "iterations": 959,
}


@dataclass
class ModelErrors:
    vx_rms: float  # mm/s
    vy_rms: float  # mm/s
    vtheta_rms: float  # rad/s
    vx_rel: float  # fraction of the true vx range
    vy_rel: float
    vtheta_rel: float
    sigma_height: float  # learned, px
    sigma_angle: float  # learned, rad
    sigma_height_rel: float  # |learned - true| / true
    sigma_angle_rel: float
    sensor_rms_px: float  # RMS of f_learned - f_true over the observed distance range

    def as_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in asdict(self).items()}


def truth_problem(truth: Any, n_commands: int | None = None) -> str | None:
    """Why a log's ``meta["truth"]`` cannot score a model ("field 'meta.truth.KEY': what is wrong"), or
    None when it can. ``meta`` is free-form JSON: the truth is checked before any score reads it, so a
    malformed one is reported (and ignored), never a crash. ``n_commands``: the command table's length
    the true velocities must match (None: any)."""
    if not isinstance(truth, dict):
        return f"field 'meta.truth': expected a JSON object, got {type(truth).__name__}"
    missing = [k for k in ("velocities", "sigma_height", "sigma_angle", "sensor") if k not in truth]
    if missing:
        return f"field 'meta.truth': missing key(s) {', '.join(missing)}"
    rows = n_commands if n_commands is not None else "A"
    try:
        vel = np.asarray(truth["velocities"], dtype=float)
    except (TypeError, ValueError):
        vel = None
    if vel is None or vel.ndim != 2 or vel.shape[1] != 3 or not len(vel) or (n_commands is not None and
                                                                         len(vel) != n_commands):
        got = "not a table of numbers" if vel is None else f"shape {vel.shape}"
        return f"field 'meta.truth.velocities': expected shape ({rows}, 3) (mm/s, mm/s, rad/s), got {got}"
    if not np.isfinite(vel).all():
        return "field 'meta.truth.velocities': non-finite value"
    for key in ("sigma_height", "sigma_angle"):
        if not _positive(truth[key]):
            return f"field 'meta.truth.{key}': expected a positive number, got {truth[key]!r}"
    return _sensor_problem(truth["sensor"])


def _positive(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and bool(np.isfinite(x)) and x > 0


def _sensor_problem(sensor: Any) -> str | None:
    """The check of ``meta.truth.sensor``: ``{"model": "pinhole", "height_px_mm"}`` or ``{"model": "curve",
    "basis", "coef"}`` (``true_height``)."""
    def where(key: str = "") -> str:
        return f"field 'meta.truth.sensor{'.' + key if key else ''}'"

    if not isinstance(sensor, dict):
        return f"{where()}: expected a JSON object, got {type(sensor).__name__}"
    if sensor.get("model") == "pinhole":
        k = sensor.get("height_px_mm")
        return None if _positive(k) else f"{where('height_px_mm')}: expected a positive number, got {k!r}"
    if sensor.get("model") == "curve":
        if sensor.get("basis") not in BASES:
            return f"{where('basis')}: expected one of {', '.join(BASES)}, got {sensor.get('basis')!r}"
        coef = sensor.get("coef")
        ok = isinstance(coef, list) and coef and all(isinstance(c, (int, float)) and not isinstance(c, bool)
                                                    and np.isfinite(c) for c in coef)
        return None if ok else f"{where('coef')}: expected a non-empty list of finite numbers, got {coef!r}"
    return f"{where('model')}: expected 'pinhole' or 'curve', got {sensor.get('model')!r}"


def true_height(truth: dict[str, Any], d: np.ndarray) -> np.ndarray:
    """The simulator's mean beacon height (px) at distance d (mm): pinhole k / d, or the curve of a
    calibrated simulator (``{"model": "curve", "basis", "coef"}``)."""
    sensor = truth["sensor"]
    d = np.asarray(d, float)
    if sensor.get("model") == "curve":
        return curve(BASES[sensor["basis"]], sensor["coef"], d)[0]
    if sensor.get("model") != "pinhole":
        raise ValueError(f"unknown true sensor model {sensor.get('model')!r}")
    return float(sensor["height_px_mm"]) / d


def velocity_errors(learned: np.ndarray, true: np.ndarray, executed: np.ndarray | None = None) -> dict[str, float]:
    """RMS error per component over executed actions; relative to each true component's range."""
    learned, true = np.asarray(learned, float), np.asarray(true, float)
    mask = np.ones(len(true), bool) if executed is None else np.asarray(executed, bool)
    rms = np.sqrt(np.mean((learned[mask] - true[mask]) ** 2, axis=0))
    span = true.max(axis=0) - true.min(axis=0)
    names = ("vx", "vy", "vtheta")
    out = {f"{n}_rms": float(r) for n, r in zip(names, rms)}
    out.update({f"{n}_rel": float(r / s) if s > 0 else float("nan") for n, r, s in zip(names, rms, span)})
    return out


def sensor_rms(sensor: SensorModel, truth: dict[str, Any], d_range: tuple[float, float], n: int = 400) -> float:
    """RMS (px) of learned minus true mean height on a uniform grid over ``d_range`` (mm)."""
    d = np.linspace(d_range[0], d_range[1], n)
    return float(np.sqrt(np.mean((sensor.mean(d) - true_height(truth, d)) ** 2)))


def velocity_bound(se_velocities, true_velocities) -> dict[str, float]:
    """The information bound of one log: the RMS over commands of the velocities' standard errors (NaN rows,
    commands never executed, left out), relative to each component's true range (the errors' yardstick):
    ``{"vx_bound", "vy_bound", "vtheta_bound"}``. An efficient learner's error is about this on average."""
    se = np.array(se_velocities, dtype=float)
    true = np.asarray(true_velocities, float)
    span = true.max(axis=0) - true.min(axis=0)
    rms = np.sqrt(np.nanmean(se**2, axis=0))
    return {f"{n}_bound": float(r / w) for n, r, w in zip(("vx", "vy", "vtheta"), rms, span)}


def observed_distance_range(logs) -> tuple[float, float]:
    """(min, max) true distance (mm) of the sightings in logs that carry poses."""
    ds = []
    for tr in logs:
        if tr.pose is None:
            continue
        xy = tr.pose[tr.sighting_frame + 1, :2]
        ds.append(np.hypot(*(tr.landmarks[tr.sighting_landmark] - xy).T))
    if not ds:
        raise ValueError("no log with true poses")
    d = np.concatenate(ds)
    return float(d.min()), float(d.max())


def continuous_velocity_errors(params: Model, logs) -> dict[str, float]:
    """RMS velocity errors over every frame's command of continuous-command ``logs`` whose truth gives
    a feature map and true weights (``aibo_gym.collect_wheeled``: velocity per unit feature)."""
    truth = logs[0].truth
    if "weights" not in truth or "feature_map" not in truth:
        raise ValueError("the log's truth has no true 'weights' and 'feature_map' for its continuous commands")
    commands = np.concatenate([tr.controls for tr in logs])
    true = features(truth["feature_map"], commands) @ np.asarray(truth["weights"], dtype=float)
    return velocity_errors(params.action.velocity(commands), true)


def model_errors(params: Model, logs) -> ModelErrors:
    """All errors of ``params`` against the truth of ``logs`` (simulated, same robot)."""
    truth = logs[0].truth
    if truth is None:
        raise ValueError("log has no ground truth (meta['truth'])")
    if params.action.discrete:
        problem = truth_problem(truth, len(params.action.weights))
        if problem:
            raise ValueError(problem)
        executed = np.zeros(len(params.action.weights), bool)
        for tr in logs:
            executed[np.unique(tr.actions)] = True
        v = velocity_errors(params.action.velocities, np.asarray(truth["velocities"]), executed)
    else:
        v = continuous_velocity_errors(params, logs)
    sh = float(truth.get("sigma_height", truth.get("sigma_range_mm", np.nan)))
    sa = float(truth.get("sigma_angle", truth.get("sigma_bearing", np.nan)))
    s = params.sensor
    return ModelErrors(
        **v,
        sigma_height=s.sigma_size,
        sigma_angle=s.sigma_bearing,
        sigma_height_rel=abs(s.sigma_size - sh) / sh,
        sigma_angle_rel=abs(s.sigma_bearing - sa) / sa,
        sensor_rms_px=sensor_rms(s, truth, observed_distance_range(logs)),
    )
