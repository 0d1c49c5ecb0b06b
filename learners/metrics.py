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
from learners.inference.lowered import curve
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
