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
range (widened by 3 sigma_range), and, when a path is known (the log's true poses, e.g. Vicon, else the model's
smoothed path: ``experiments.calibrated.smoothed_paths``), the detection probability, sightings / landmarks within
the camera's view in the image frames, overall (``detect_prob``) and by distance (``detect_by_distance``: a real
camera's falls with it, MRCLAM's from about 0.55 at 1-2 m to 0.2 beyond 5 m) and by the angle off the heading
(``detect_by_angle``: on two of the MRCLAM robots it falls at the image's edge), docs/results.md, "The twin's replays
follow the robot's path".
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
#: ``detect_by_distance``: the landmarks in view split at the quantiles of their distance into at most this many
#: bins, each holding at least ``DETECT_MIN_PAIRS`` (landmark, image) pairs
DETECT_BINS = 8
ANGLE_BINS = 5
DETECT_MIN_PAIRS = 100
IPF_ITERATIONS = 50  # the two tables' fit: each pass a product closer to the binned counts' margins


def check_model(model: Model) -> None:
    """ValueError (one line) when ``WheeledRobot-v0`` cannot represent ``model``."""
    act, sen = model.action, model.sensor
    if act.feature_map not in FEATURE_MAPS:
        raise ValueError(f"the wheeled simulator takes continuous commands ({', '.join(FEATURE_MAPS)}); this "
                         f"model's action model is '{act.feature_map}'")
    if sen.kind != "range_mm":
        raise ValueError(f"the wheeled simulator's camera reports ranges in mm; this model's sensor is '{sen.kind}'")


def wheeled_config(model: Model, log: Trajectory | None = None, index: int = 0,
                   path: np.ndarray | None = None) -> dict[str, Any]:
    """The ``WheeledRobot-v0`` config of ``model``'s simulator (module docstring); ``log`` (the measured
    one, the ``index``-th of the fit) gives landmarks, field, camera and command bounds; its camera's detection is
    measured at its true poses, else at ``path`` ((T + 1, 3) poses)."""
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
        cfg.update(_from_log(log, float(sen.sigma_size), path))
    start = model.init[min(index, len(model.init) - 1)].mean
    cfg["start_pose"] = [float(start[0]), float(start[1]), float(start[2])]
    if cfg["walls"] != "open" and "field" in cfg:
        half = np.asarray(cfg["field"], float) / 2
        cfg["start_pose"][:2] = np.clip(start[:2], -half, half).tolist()
    return cfg


def camera_measured(log: Trajectory) -> bool:
    """Whether ``log``'s camera is measured (it was not made by ``WheeledRobot-v0``, whose settings it would carry in
    ``meta["config"]``)."""
    made_here = log.meta.get("config") if isinstance(log.meta.get("config"), dict) else {}
    return not all(k in made_here for k in CAMERA_KEYS)


def needs_path(log: Trajectory) -> bool:
    """Whether ``log``'s camera is measured at a model's smoothed path: it is measured (``camera_measured``) and the
    log has no true poses to measure it at."""
    return log.pose is None and camera_measured(log)


def _from_log(log: Trajectory, sigma_range: float, path: np.ndarray | None = None) -> dict[str, Any]:
    """Landmarks, field, command bounds, camera and episode length of the measured ``log``."""
    c = log.controls
    lo, hi = c.min(axis=0), c.max(axis=0)
    out: dict[str, Any] = {
        "beacons": log.landmarks.tolist(),
        "field": (log.field if log.field is not None else
                  2.0 * (np.abs(log.landmarks).max(axis=0) + FIELD_MARGIN_MM)).tolist(),
        "max_steps": int(log.n_frames),
        "control_low": np.minimum(lo, -1.0).tolist(), "control_high": np.maximum(hi, 1.0).tolist(),
    }
    if camera_measured(log):
        out.update(measured_camera(log, sigma_range, path))
    else:
        out.update({k: log.meta["config"][k] for k in CAMERA_KEYS})
    return out


def measured_camera(log: Trajectory, sigma_range: float, path: np.ndarray | None = None) -> dict[str, Any]:
    """Field of view, range limits and detection probability measured on a log (module docstring), the detection at
    the log's true poses, else at ``path`` (neither: not measured); the images are the frames with a sighting (given
    to the replay as a mask), so ``image_prob`` is 1."""
    cam: dict[str, Any] = {"image_every": 1, "image_prob": 1.0}
    if log.n_sightings == 0:
        return cam
    r, b = log.sighting_value[:, 0], log.sighting_value[:, 1]
    cam["fov"] = min(2.0 * (float(np.abs(b).max()) + FOV_MARGIN_RAD), 2.0 * math.pi)
    cam["range_mm"] = [max(0.0, float(r.min()) - 3.0 * sigma_range), float(r.max()) + 3.0 * sigma_range]
    path = log.pose if log.pose is not None else path
    if path is None:
        return cam
    view, seen = _in_view(log, path, cam["fov"], cam["range_mm"])
    if len(view):
        cam["detect_prob"] = float(min(1.0, len(seen) / len(view)))
        cam.update(detection_tables(view, seen))
    return cam


def _in_view(log: Trajectory, path: np.ndarray, fov: float, range_mm: list[float]) -> tuple[np.ndarray, np.ndarray]:
    """((n, 2) distance mm and |angle off the heading| rad at ``path`` of the (landmark, image frame) pairs within
    view, (S, 2) the same of every sighting's landmark)."""
    frames = np.flatnonzero(image_frames(log))
    pose = path[frames + 1]
    dx = log.landmarks[None, :, 0] - pose[:, None, 0]
    dy = log.landmarks[None, :, 1] - pose[:, None, 1]
    d = np.hypot(dx, dy)
    angle = np.abs(np.angle(np.exp(1j * (np.arctan2(dy, dx) - pose[:, None, 2]))))
    visible = (d >= range_mm[0]) & (d <= range_mm[1]) & (angle <= fov / 2)
    i, j = np.searchsorted(frames, log.sighting_frame), log.sighting_landmark
    return np.stack([d[visible], angle[visible]], axis=1), np.stack([d[i, j], angle[i, j]], axis=1)


def detection_tables(view: np.ndarray, seen: np.ndarray) -> dict[str, list[list[float]]]:
    """``detect_by_distance`` and ``detect_by_angle`` of the pairs in ``view`` and the sightings ``seen`` (each (n, 2):
    distance mm, |angle| rad): the detection probability as a product p(d) g(|a|) over quantile bins of each (at most
    ``DETECT_BINS`` and ``ANGLE_BINS``, each of ``DETECT_MIN_PAIRS`` pairs or more), fitted by iterative
    proportional fitting (the independence model's maximum likelihood for the binned counts; Deming & Stephan 1940),
    g scaled to mean 1 over the pairs in view. A table left out where its variable has too few pairs for two bins."""
    bins = [min(most, len(view) // DETECT_MIN_PAIRS) for most in (DETECT_BINS, ANGLE_BINS)]
    edges = [_edges(view[:, k], b) for k, b in enumerate(bins)]
    n_view = np.histogram2d(view[:, 0], view[:, 1], edges)[0]
    n_seen = np.histogram2d(seen[:, 0], seen[:, 1], edges)[0]
    p, g = np.ones(n_view.shape[0]), np.ones(n_view.shape[1])
    for _ in range(IPF_ITERATIONS):
        p = n_seen.sum(axis=1) / np.maximum(n_view @ g, 1e-12)
        g = n_seen.sum(axis=0) / np.maximum(p @ n_view, 1e-12)
    mean_g = (n_view.sum(axis=0) @ g) / n_view.sum()
    p, g = p * mean_g, g / mean_g
    out = {}
    for key, values, k in (("detect_by_distance", np.minimum(p, 1.0), 0), ("detect_by_angle", g, 1)):
        held = n_view.sum(axis=1 - k) > 0  # a bin between tied quantiles holds no pair: no point of the table
        centre = _bin_means(view[:, k], edges[k])[held]
        if held.sum() >= 2 and np.all(np.diff(centre) > 0):
            out[key] = [[float(c), float(v)] for c, v in zip(centre, values[held])]
    return out


def _edges(x: np.ndarray, bins: int) -> np.ndarray:
    """Quantile edges of ``x`` in at most ``bins`` bins (tied quantiles merged; one bin below 2), open at both ends (a
    sighting beyond the pairs in view counts in the end bins)."""
    inner = np.unique(np.quantile(x, np.linspace(0.0, 1.0, bins + 1)[1:-1])) if bins >= 2 else np.zeros(0)
    return np.concatenate([[-np.inf], inner, [np.inf]])


def _bin_means(x: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """The mean of ``x`` in each bin of ``edges`` (0 in an empty one)."""
    k = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
    return np.bincount(k, weights=x, minlength=len(edges) - 1) / np.maximum(np.bincount(k, minlength=len(edges) - 1), 1)


def image_frames(log: Trajectory) -> np.ndarray:
    """(T,) bool: the frames of ``log`` with at least one sighting (the images a replay takes)."""
    return np.bincount(log.sighting_frame, minlength=log.n_frames) > 0
