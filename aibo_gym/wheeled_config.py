"""The one configuration dict of ``WheeledRobot-v0`` (highway-env style), like :mod:`aibo_gym.config`.

:func:`default_config` lists every key with its default; :func:`make_config` merges a user's (partial)
dict into it and validates it: an unknown key or a bad value raises a one-line ValueError naming the
key. Units: mm, rad, s. The defaults are a small differential-drive robot among 8 landmarks, with the
camera of the UTIAS MRCLAM robots (field of view +-0.59 rad, ranges up to 8.5 m, dt 0.1 s).

==================  ======================================  ==========================================
key                 default                                 meaning
==================  ======================================  ==========================================
field               [6000, 6000]                            area length (x), width (y), mm, origin at the
                                                            centre: the walls (if any), random starts
beacons             8 landmarks (``DEFAULT_LANDMARKS``)     landmark positions (B x 2), mm
dt                  0.1                                     seconds per frame
max_steps           6000                                    frames before ``truncated`` (10 min)
control_names       ["v_mm_s", "omega_rad_s"]               names with units of the k command components
control_low         [-300, -1.5]                            action space lower bound per component
control_high        [300, 1.5]                              action space upper bound per component
feature_map         "diff_drive"                            "diff_drive", "unicycle" (both k = 2) or
                                                            "linear" (any k): see :mod:`aibo_core.features`
weights             None                                    F x 3 true velocity per unit feature (mm/s,
                                                            mm/s, rad/s); None: ``DEFAULT_WEIGHTS`` (diff
                                                            drive, unicycle; linear with k = 2)
motion_cov          diag(9, 1, 1e-4)                        3 x 3 per-frame robot-frame motion noise
                                                            covariance (mm^2, rad^2), SPD (not None;
                                                            near-noise-free: e.g. 1e-12 * identity)
sensor_curve        {"basis": "power", "coef": [0, 1]}      measured range (mm) = sum c_k d^k (power) or
                                                            sum c_k d^-k (inverse), d mm; default range = d.
                                                            Both keys: a dict replaces the default whole
                                                            (a coef means nothing without its basis)
sigma_range_mm      50                                      range noise std, mm
sigma_bearing       0.02                                    bearing noise std, rad
fov                 1.18                                    camera field of view (total), rad, centred
                                                            on the heading, 0 < fov <= 2 pi
range_mm            [300, 8500]                             distances at which a landmark is seen, mm
                                                            (never closer than ``camera.MIN_SIGHT_MM``, 1)
detect_prob         0.9                                     probability a visible landmark is reported
detect_by_distance  None                                    or [[d_mm, p], ...], d increasing: the
                                                            probability by distance (linear between the
                                                            points, held beyond them), instead of
                                                            detect_prob (a real camera's falls with d)
detect_by_angle     None                                    or [[|a| rad, factor], ...], |a| increasing:
                                                            the probability times this factor at the
                                                            landmark's angle a off the heading (linear
                                                            between, held beyond), at most 1
image_every         1                                       an image every n-th frame (frames n-1, 2n-1 ...)
image_prob          1.0                                     probability that a scheduled frame takes an image
walls               "open"                                  "open" (none, the episode goes on anywhere),
                                                            "none" (leaving the field ends it), "clamp",
                                                            "pymunk" (:mod:`aibo_gym.walls`)
robot_radius        150                                     body radius for walls="pymunk", mm
pymunk_substeps     4                                       physics substeps per frame
effects             {}                                      {name: {param: value}} (:mod:`aibo_gym.catalogue`)
start_pose          [0, 0, 0]                               (x mm, y mm, theta rad) or "random"
==================  ======================================  ==========================================
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from aibo_core.features import ZERO_OUTPUTS, n_features

from .config import (
    WALL_MODES,
    _bad,
    _beacons,
    _choice,
    _fov,
    _int_min,
    _num,
    _numbers,
    _pair_positive,
    _positive,
    _prob,
    _range_mm,
    _rows,
    _start_pose,
    check_field_fit,
    covariance,
    merge_config,
    sensor_curve,
)
from .effects import finalize_effects, validate_effects

DEFAULT_LANDMARKS = [[2500.0, 2500.0], [0.0, 2800.0], [-2500.0, 2500.0], [-2800.0, 0.0],
                     [-2500.0, -2500.0], [0.0, -2800.0], [2500.0, -2500.0], [2800.0, 0.0]]
#: The default robot (rows: v, omega, v|omega|, |omega|, 1; columns vx mm/s, vy mm/s, vtheta rad/s):
#: 4% short on speed, 7% short on turns, loses speed while turning, drifts left at 0.004 rad/s.
DEFAULT_WEIGHTS = [[0.96, 0.0, 0.0], [0.0, 0.0, 0.93], [-0.15, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.004]]
FEATURE_MAP_NAMES = ("diff_drive", "unicycle", "linear")


def default_config() -> dict[str, Any]:
    """A fresh dict of every config key with its default value (see the module docstring)."""
    return {
        "field": [6000.0, 6000.0],
        "beacons": [list(b) for b in DEFAULT_LANDMARKS],
        "dt": 0.1,
        "max_steps": 6000,
        "control_names": ["v_mm_s", "omega_rad_s"],
        "control_low": [-300.0, -1.5],
        "control_high": [300.0, 1.5],
        "feature_map": "diff_drive",
        "weights": None,
        "motion_cov": [[9.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1e-4]],
        "sensor_curve": {"basis": "power", "coef": [0.0, 1.0]},
        "sigma_range_mm": 50.0,
        "sigma_bearing": 0.02,
        "fov": 1.18,
        "range_mm": [300.0, 8500.0],
        "detect_prob": 0.9,
        "detect_by_distance": None,
        "detect_by_angle": None,
        "image_every": 1,
        "image_prob": 1.0,
        "walls": "open",
        "robot_radius": 150.0,
        "pymunk_substeps": 4,
        "effects": {},
        "start_pose": [0.0, 0.0, 0.0],
    }


def _control_names(key: str, v: Any) -> list[str]:
    if not isinstance(v, (list, tuple)) or not v or not all(isinstance(n, str) and n for n in v):
        raise _bad(key, v, "a non-empty list of non-empty names, e.g. ['v_mm_s', 'omega_rad_s']")
    return list(v)


def _vector(key: str, v: Any) -> list[float]:
    return _numbers(key, v, None, "a list of finite numbers, one per control")


def _weights(key: str, v: Any) -> list[list[float]] | None:
    if v is None:
        return None
    return _rows(key, v, None, 3, "None or an F x 3 list of velocities per unit feature (mm/s, mm/s, rad/s)")


def _sigma(key: str, v: Any) -> float:
    x = _num(key, v, "a number >= 0")
    if x < 0:
        raise _bad(key, v, "a number >= 0")
    return x


def _table(what: str, top: float) -> Callable[[str, Any], list[list[float]] | None]:
    """A check of a table of [x >= 0, value in [0, top]] pairs, x increasing."""
    want = f"None or a list of [{what}, value in [0, {top:g}]] pairs, the first >= 0 and increasing"

    def check(key: str, v: Any) -> list[list[float]] | None:
        if v is None:
            return None
        rows = _rows(key, v, None, 2, want)
        x, y = np.array(rows).T
        if np.any(x < 0) or np.any(np.diff(x) <= 0) or np.any((y < 0) | (y > top)):
            raise _bad(key, v, want)
        return rows
    return check


CHECKS: dict[str, Callable[[str, Any], Any]] = {
    "field": _pair_positive,
    "beacons": _beacons,
    "dt": _positive,
    "max_steps": _int_min(1),
    "control_names": _control_names,
    "control_low": _vector,
    "control_high": _vector,
    "feature_map": _choice(FEATURE_MAP_NAMES),
    "weights": _weights,
    "motion_cov": covariance,
    "sensor_curve": sensor_curve,
    "sigma_range_mm": _sigma,
    "sigma_bearing": _sigma,
    "fov": _fov,
    "range_mm": _range_mm,
    "detect_prob": _prob,
    "detect_by_distance": _table("distance mm", 1.0),
    "detect_by_angle": _table("|angle| rad", 1e6),
    "image_every": _int_min(1),
    "image_prob": _prob,
    "walls": _choice(WALL_MODES),
    "robot_radius": _positive,
    "pymunk_substeps": _int_min(1),
    "effects": lambda k, v: validate_effects(v),
    "start_pose": _start_pose,
}


def _check_controls(cfg: dict[str, Any]) -> None:
    k = len(cfg["control_names"])
    for key in ("control_low", "control_high"):
        if len(cfg[key]) != k:
            raise _bad(key, cfg[key], f"{k} numbers (one per control in 'control_names')")
    if any(lo >= hi for lo, hi in zip(cfg["control_low"], cfg["control_high"])):
        raise _bad("control_high", cfg["control_high"], f"numbers above 'control_low' {cfg['control_low']}")
    try:
        n = n_features(cfg["feature_map"], k)
    except ValueError as err:
        raise ValueError(f"config key 'feature_map': {err}") from None
    if cfg["weights"] is None:
        if cfg["feature_map"] == "linear" and k != 2:
            raise _bad("weights", None, f"a {n} x 3 list: the 'linear' map has no default for {k} controls")
        cfg["weights"] = [list(r) for r in (DEFAULT_WEIGHTS if cfg["feature_map"] != "linear" else
                                            [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])]
    if len(cfg["weights"]) != n:
        raise _bad("weights", cfg["weights"], f"{n} rows of 3 (the '{cfg['feature_map']}' map has {n} features "
                   f"for {k} controls)")
    for col in ZERO_OUTPUTS.get(cfg["feature_map"], ()):
        if any(row[col] != 0.0 for row in cfg["weights"]):
            raise _bad("weights", cfg["weights"], f"column {col} all 0 (the '{cfg['feature_map']}' map moves no "
                       "velocity there)")


def _cross_checks(cfg: dict[str, Any]) -> None:
    _check_controls(cfg)
    check_field_fit(cfg)


def make_config(config: dict[str, Any] | None = None) -> dict[str, Any]:
    """Merge ``config`` into :func:`default_config`, validate, and return the full normalized dict
    (``weights`` filled in). Raises a one-line ValueError naming the key on an unknown key or a bad value."""
    cfg = merge_config(default_config(), config, whole=("sensor_curve",))
    out = {key: CHECKS[key](key, value) for key, value in cfg.items()}
    _cross_checks(out)
    out["effects"] = finalize_effects(out["effects"], out)
    return out


def true_weights(cfg: dict[str, Any]) -> np.ndarray:
    """(F, 3) true velocity per unit feature of a validated config (mm/s, mm/s, rad/s)."""
    return np.asarray(cfg["weights"], dtype=float)

