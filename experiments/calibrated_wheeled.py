"""The calibrated simulator of a velocity-commanded robot: ``WheeledRobot-v0`` built from a fitted model
whose action model has continuous commands (``diff_drive``, ``unicycle``, ``linear``) and whose sensor
reports ranges (``range_mm``); used by :mod:`experiments.calibrated` for such models.

From the model: the true velocity per unit feature (``weights`` / dt), the per-frame motion covariance,
the range curve and its noise, the bearing noise, the effects (their simulator twins, same names and
parameters) and the start pose; no walls unless the model has ``wall_contact``. From the measured log:
the landmarks, the field (or the landmarks' bounding box), the frames that took an image (the frames
with a sighting: a replay images exactly those) and the camera. When the log was made by
``WheeledRobot-v0`` its camera settings are copied (``meta["config"]``); otherwise (a real robot) they are
measured: the field of view from the widest bearing, the range limits from the shortest and longest
range (widened by 3 sigma_range), and, when the log has true poses (e.g. Vicon), the detection
probability: sightings / landmarks within the camera's view in the image frames.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from aibo_core.trajectory import Trajectory
from learners.model.model import Model

FEATURE_MAPS = ("diff_drive", "unicycle", "linear")
#: Camera settings taken from a log made by ``WheeledRobot-v0`` (``meta["config"]``).
CAMERA_KEYS = ("fov", "range_mm", "detect_prob", "image_every", "image_prob")
FIELD_MARGIN_MM = 1000.0  # a log without a field: the landmarks' bounding box grown by this
FOV_MARGIN_RAD = 0.01  # the measured field of view: the widest bearing plus this, each side


def check_model(model: Model) -> None:
    """ValueError (one line) when ``WheeledRobot-v0`` cannot represent ``model``."""
    act, sen = model.action, model.sensor
    if act.feature_map not in FEATURE_MAPS:
        raise ValueError(f"the wheeled simulator takes continuous commands ({', '.join(FEATURE_MAPS)}); this "
                         f"model's action model is '{act.feature_map}'")
    if sen.kind != "range_mm":
        raise ValueError(f"the wheeled simulator's camera reports ranges in mm; this model's sensor is '{sen.kind}'")


def wheeled_config(model: Model, log: Trajectory | None = None, index: int = 0) -> dict[str, Any]:
    """The ``WheeledRobot-v0`` config of ``model``'s simulator (module docstring); ``log`` (the measured
    one, the ``index``-th of the fit) gives landmarks, field, camera and command bounds."""
    check_model(model)
    act, sen = model.action, model.sensor
    names = list(act.control_names) or (list(log.control_names) if log is not None else [])
    cfg: dict[str, Any] = {
        "dt": act.dt, "feature_map": act.feature_map, "weights": (act.weights / act.dt).tolist(),
        "motion_cov": act.cov.tolist(), "sensor_curve": {"basis": sen.basis, "coef": [float(c) for c in sen.coef]},
        "sigma_range_mm": float(sen.sigma_size), "sigma_bearing": float(sen.sigma_bearing),
        "effects": {e.name: e.to_json()["parameters"] for e in model.effects},
        "walls": "clamp" if model.effect("wall_contact") is not None else "open",
    }
    if names:
        cfg["control_names"] = names
        k = len(names)
        cfg["control_low"], cfg["control_high"] = [-300.0, -1.5][:k] + [-1.0] * (k - 2), [300.0, 1.5][:k] + [1.0] * (k - 2)
    if log is not None:
        cfg.update(_from_log(log, float(sen.sigma_size)))
    start = model.init[min(index, len(model.init) - 1)].mean
    cfg["start_pose"] = [float(start[0]), float(start[1]), float(start[2])]
    if cfg["walls"] != "open" and "field" in cfg:
        half = np.asarray(cfg["field"], float) / 2
        cfg["start_pose"][:2] = np.clip(start[:2], -half, half).tolist()
    return cfg


def _from_log(log: Trajectory, sigma_range: float) -> dict[str, Any]:
    """Landmarks, field, command bounds, camera and episode length of the measured ``log``."""
    made_here = log.meta.get("config") if isinstance(log.meta.get("config"), dict) else {}
    c = log.controls
    lo, hi = c.min(axis=0), c.max(axis=0)
    out: dict[str, Any] = {
        "beacons": log.landmarks.tolist(),
        "field": (log.field if log.field is not None else
                  2.0 * (np.abs(log.landmarks).max(axis=0) + FIELD_MARGIN_MM)).tolist(),
        "max_steps": int(log.n_frames),
        "control_low": np.minimum(lo, -1.0).tolist(), "control_high": np.maximum(hi, 1.0).tolist(),
    }
    if all(k in made_here for k in CAMERA_KEYS):
        out.update({k: made_here[k] for k in CAMERA_KEYS})
    else:
        out.update(measured_camera(log, sigma_range))
    return out


def measured_camera(log: Trajectory, sigma_range: float) -> dict[str, Any]:
    """Field of view, range limits and detection probability measured on a log (module docstring);
    the images are the frames with a sighting (given to the replay as a mask), so ``image_prob`` is 1."""
    cam: dict[str, Any] = {"image_every": 1, "image_prob": 1.0}
    if log.n_sightings == 0:
        return cam
    r, b = log.sighting_value[:, 0], log.sighting_value[:, 1]
    cam["fov"] = min(2.0 * (float(np.abs(b).max()) + FOV_MARGIN_RAD), 2.0 * math.pi)
    cam["range_mm"] = [max(0.0, float(r.min()) - 3.0 * sigma_range), float(r.max()) + 3.0 * sigma_range]
    p = detection_rate(log, cam["fov"], cam["range_mm"])
    if p is not None:
        cam["detect_prob"] = p
    return cam


def detection_rate(log: Trajectory, fov: float, range_mm: list[float]) -> float | None:
    """Sightings / (landmark, image frame) pairs within view at the true pose; None without poses."""
    if log.pose is None:
        return None
    frames = np.flatnonzero(image_frames(log))
    pose = log.pose[frames + 1]
    dx = log.landmarks[None, :, 0] - pose[:, None, 0]
    dy = log.landmarks[None, :, 1] - pose[:, None, 1]
    d = np.hypot(dx, dy)
    bearing = np.angle(np.exp(1j * (np.arctan2(dy, dx) - pose[:, None, 2])))
    visible = int(np.sum((d >= range_mm[0]) & (d <= range_mm[1]) & (np.abs(bearing) <= fov / 2)))
    return float(min(1.0, log.n_sightings / visible)) if visible else None


def image_frames(log: Trajectory) -> np.ndarray:
    """(T,) bool: the frames of ``log`` with at least one sighting (the images a replay takes)."""
    return np.bincount(log.sighting_frame, minlength=log.n_frames) > 0
