"""The one configuration dict of ``AiboBeacons-v0`` (highway-env style).

:func:`default_config` lists every key with its default; :func:`make_config` merges a user's
(partial) dict into it and validates it. An unknown key or a bad value raises ValueError naming
the key and the valid choices. Units: mm, rad, px, s.

================  ==================================  ==============================================
key               default                             meaning
================  ==================================  ==============================================
field             [5400, 3600]                        field length (x) and width (y), mm; origin at centre
beacons           [[1350, 1950], [-1350, 1950],       beacon positions (B x 2), mm
                  [-1350, -1950], [1350, -1950]]
dt                1/30                                seconds per frame
max_steps         27000                               frames before ``truncated`` (15 min at 30 fps)
robot_seed        0                                   seed of the robot's true action model only
velocities        None                                40 x 3 true velocities (mm/s, mm/s, rad/s); None: drawn
nominal_max       [355, 420, pi/2]                    nominal top speed per component over the 40 actions
                                                      (mm/s, mm/s, rad/s): what the robot *believes*
velocity_range    [710, 840, pi]                      max - min of the true velocities per component
slip_std          [3.0, 3.0, 0.02]                    per-frame robot-frame slip noise std (mm, mm, rad)
slip_cov          None                                3 x 3 per-frame slip covariance (mm^2, rad^2), symmetric
                                                      positive definite; replaces slip_std when set
big_slip_prob     0.0                                 probability per frame of an extra large slip
big_slip_std      [30, 30, 0.2]                       std of a large slip (mm, mm, rad)
pan_amplitude     1.4                                 head pan amplitude, rad (pan = A sin(2 pi t / T))
pan_period        3.0                                 head pan period T, s
fov               0.99                                camera horizontal field of view (total), rad,
                                                      0 < fov <= 2 pi
range_mm          [1275, 4175]                        distances at which a beacon is recognized, mm
                                                      (never closer than ``camera.MIN_SIGHT_MM``, 1 mm)
detect_prob       0.9                                 probability a visible beacon is detected
focal_px          190                                 camera focal length, px
beacon_height_mm  300                                 beacon height, mm (height px = focal*H/d)
sensor_curve      None                                {"basis": "power" | "inverse", "coef": [c0, c1, ...]}:
                                                      true height px = sum c_k d^k (power) or sum c_k d^-k
                                                      (inverse), d in mm; replaces focal*H/d when set
noise             "paper-sim"                         sensor noise preset: "paper-sim" or "aibo"
sigma_height      None                                px; overrides the preset when set
sigma_angle       None                                rad; overrides the preset when set
walls             "clamp"                             "clamp", "pymunk", "none" or "open" (no walls and
                                                      the episode goes on off the field)
robot_radius      150                                 robot body radius for walls="pymunk" (and only
                                                      checked there: < half the field width), mm
pymunk_substeps   4                                   fixed physics substeps per frame
effects           {}                                  {name: {param: value}}, see aibo_gym.effects and
                                                      aibo_gym.catalogue
reward            "none"                              "none" (reward 0) or "explore": the weighted sum of
                                                      the terms in info["rewards"] (see the env docstring)
reward_weights    {"balance": 1, "coverage": 1,       weight of each exploration reward term (a partial
                   "sightings": 0, "wall": 0.01,      dict updates these; unknown terms are refused)
                   "info_gain": 0}
start_pose        [0, 0, 0]                           (x mm, y mm, theta rad; on the field unless
                                                      walls="open") or "random"
================  ==================================  ==============================================
"""

from __future__ import annotations

import copy
import math
from typing import Any, Callable

import numpy as np

from .camera import MIN_SIGHT_MM
from .effects import finalize_effects, validate_effects

NOISE_PRESETS: dict[str, dict[str, float]] = {
    "paper-sim": {"sigma_height": 1.0, "sigma_angle": 0.5},  # the paper's simulation
    "aibo": {"sigma_height": 1.59, "sigma_angle": 0.0267},  # measured on the ERS-7
}
WALL_MODES = ("clamp", "pymunk", "none", "open")
SENSOR_BASES = ("power", "inverse")
REWARDS = ("none", "explore")
REWARD_TERMS = ("balance", "coverage", "sightings", "wall", "info_gain")  # aibo_gym.policies.onboard: the same
DEFAULT_REWARD_WEIGHTS = {"balance": 1.0, "coverage": 1.0, "sightings": 0.0, "wall": 0.01, "info_gain": 0.0}
START_MARGIN_MM = 500.0  # start_pose="random": distance kept from the field edge, mm


def default_config() -> dict[str, Any]:
    """A fresh dict of every config key with its default value (see the module docstring)."""
    return {
        "field": [5400.0, 3600.0],
        "beacons": [[1350.0, 1950.0], [-1350.0, 1950.0], [-1350.0, -1950.0], [1350.0, -1950.0]],
        "dt": 1.0 / 30.0,
        "max_steps": 27000,
        "robot_seed": 0,
        "velocities": None,
        "nominal_max": [355.0, 420.0, math.pi / 2],
        "velocity_range": [710.0, 840.0, math.pi],
        "slip_std": [3.0, 3.0, 0.02],
        "slip_cov": None,
        "big_slip_prob": 0.0,
        "big_slip_std": [30.0, 30.0, 0.2],
        "pan_amplitude": 1.4,
        "pan_period": 3.0,
        "fov": 0.99,
        "range_mm": [1275.0, 4175.0],
        "detect_prob": 0.9,
        "focal_px": 190.0,
        "beacon_height_mm": 300.0,
        "sensor_curve": None,
        "noise": "paper-sim",
        "sigma_height": None,
        "sigma_angle": None,
        "walls": "clamp",
        "robot_radius": 150.0,
        "pymunk_substeps": 4,
        "effects": {},
        "reward": "none",
        "reward_weights": dict(DEFAULT_REWARD_WEIGHTS),
        "start_pose": [0.0, 0.0, 0.0],
    }


# ---------------------------------------------------------------- value checks
def _bad(key: str, value: Any, want: str) -> ValueError:
    return ValueError(f"config key '{key}': invalid value {value!r} (expected {want})")


def _num(key: str, v: Any, want: str = "a finite number") -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not math.isfinite(v):
        raise _bad(key, v, want)
    return float(v)


def _numbers(key: str, v: Any, n: int | None, want: str) -> list[float]:
    if isinstance(v, np.ndarray):
        v = v.tolist()
    if not isinstance(v, (list, tuple)) or (n is not None and len(v) != n):
        raise _bad(key, v, want)
    return [_num(key, x, want) for x in v]


def _positive(key: str, v: Any) -> float:
    x = _num(key, v, "a positive number")
    if x <= 0:
        raise _bad(key, v, "a positive number")
    return x


def _int_min(lo: int) -> Callable[[str, Any], int]:
    def check(key: str, v: Any) -> int:
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
            raise _bad(key, v, f"an integer >= {lo}")
        return int(v)
    return check


def _triple(nonneg: bool, positive: bool = False) -> Callable[[str, Any], list[float]]:
    want = "3 positive numbers" if positive else ("3 numbers >= 0" if nonneg else "3 numbers")

    def check(key: str, v: Any) -> list[float]:
        xs = _numbers(key, v, 3, want)
        if (positive and min(xs) <= 0) or (nonneg and min(xs) < 0):
            raise _bad(key, v, want)
        return xs
    return check


def _prob(key: str, v: Any) -> float:
    x = _num(key, v, "a probability in [0, 1]")
    if not 0.0 <= x <= 1.0:
        raise _bad(key, v, "a probability in [0, 1]")
    return x


def _choice(choices: tuple[str, ...]) -> Callable[[str, Any], str]:
    def check(key: str, v: Any) -> str:
        if v not in choices:
            raise ValueError(
                f"config key '{key}': invalid value {v!r} (valid choices: {', '.join(map(repr, choices))})"
            )
        return v
    return check


def _pair_positive(key: str, v: Any) -> list[float]:
    xs = _numbers(key, v, 2, "2 positive numbers (length, width) mm")
    if min(xs) <= 0:
        raise _bad(key, v, "2 positive numbers (length, width) mm")
    return xs


def _rows(key: str, v: Any, n_rows: int | None, n_cols: int, want: str) -> list[list[float]]:
    """``v`` as a non-empty list of ``n_rows`` (None: any number of) rows of ``n_cols`` numbers, else the
    one-line error naming ``key`` and ``want``."""
    if isinstance(v, np.ndarray):
        v = v.tolist()
    if not isinstance(v, (list, tuple)) or len(v) == 0 or (n_rows is not None and len(v) != n_rows):
        raise _bad(key, v, want)
    return [_numbers(key, row, n_cols, want) for row in v]


def _beacons(key: str, v: Any) -> list[list[float]]:
    return _rows(key, v, None, 2, "a non-empty list of [x, y] positions, mm")


def _velocities(key: str, v: Any) -> list[list[float]] | None:
    if v is None:
        return None
    return _rows(key, v, 40, 3, "None or a 40 x 3 list of velocities (mm/s, mm/s, rad/s)")


def _angle_range(key: str, v: Any, hi: float) -> float:
    x = _num(key, v, f"a number in [0, {hi:.4g}]")
    if not 0.0 <= x <= hi:
        raise _bad(key, v, f"a number in [0, {hi:.4g}]")
    return x


def _fov(key: str, v: Any) -> float:
    want = f"a number in (0, {2 * math.pi:.4g}] rad (0 < fov <= 2 pi)"
    x = _num(key, v, want)
    if not 0.0 < x <= 2 * math.pi:
        raise _bad(key, v, want)
    return x


def _range_mm(key: str, v: Any) -> list[float]:
    want = f"[min, max] mm with 0 <= min < max and max >= {MIN_SIGHT_MM:g} (nothing closer is ever seen)"
    xs = _numbers(key, v, 2, want)
    if not (0 <= xs[0] < xs[1] and xs[1] >= MIN_SIGHT_MM):
        raise _bad(key, v, want)
    return xs


def _sigma(key: str, v: Any) -> float | None:
    if v is None:
        return None
    x = _num(key, v, "None or a number >= 0")
    if x < 0:
        raise _bad(key, v, "None or a number >= 0")
    return x


COVARIANCE_WANT = "a 3 x 3 symmetric positive definite covariance (mm^2, rad^2)"
CURVE_WANT = '{"basis": "power" | "inverse", "coef": [c0, c1, ...]} with both keys'


def covariance(key: str, v: Any, want: str = COVARIANCE_WANT) -> list[list[float]]:
    """``v`` as a symmetric positive definite 3 x 3 covariance (mm^2, rad^2; symmetrized), else the one-line
    error naming ``key`` and ``want`` (what the key accepts)."""
    m = np.array(_rows(key, v, 3, 3, want))
    if not np.allclose(m, m.T, rtol=1e-9, atol=1e-12) or np.linalg.eigvalsh(0.5 * (m + m.T)).min() <= 0:
        raise _bad(key, v, want)
    return (0.5 * (m + m.T)).tolist()


def _slip_cov(key: str, v: Any) -> list[list[float]] | None:
    return None if v is None else covariance(key, v, f"None or {COVARIANCE_WANT}")


def _sensor_curve(key: str, v: Any) -> dict[str, Any] | None:
    return None if v is None else sensor_curve(key, v, f"None or {CURVE_WANT}")


def sensor_curve(key: str, v: Any, want: str = CURVE_WANT) -> dict[str, Any]:
    """``v`` as a sensor curve {"basis", "coef"} (both keys: a partial dict is refused, since a coef means
    nothing without its basis), else the one-line error naming ``key`` and ``want``."""
    if not isinstance(v, dict) or set(v) != {"basis", "coef"}:
        raise _bad(key, v, want)
    basis = _choice(SENSOR_BASES)(f"{key}.basis", v["basis"])
    coef = _numbers(f"{key}.coef", v["coef"], None, "a non-empty list of finite numbers")
    if not coef:
        raise _bad(f"{key}.coef", v["coef"], "a non-empty list of finite numbers")
    return {"basis": basis, "coef": coef}


def _reward_weights(key: str, v: Any) -> dict[str, float]:
    if not isinstance(v, dict):
        raise _bad(key, v, "a dict {term: weight}")
    out = {}
    for term, w in v.items():
        if term not in REWARD_TERMS:
            raise ValueError(f"config key '{key}': unknown reward term {term!r} (valid terms: {', '.join(REWARD_TERMS)})")
        out[term] = _num(key, w, f"a finite number for the weight of '{term}'")
    return {t: out.get(t, 0.0) for t in REWARD_TERMS}


def _start_pose(key: str, v: Any) -> str | list[float]:
    if isinstance(v, str):
        return _choice(("random",))(key, v)
    return _numbers(key, v, 3, "'random' or [x mm, y mm, theta rad]")


CHECKS: dict[str, Callable[[str, Any], Any]] = {
    "field": _pair_positive,
    "beacons": _beacons,
    "dt": _positive,
    "max_steps": _int_min(1),
    "robot_seed": _int_min(0),
    "velocities": _velocities,
    "nominal_max": _triple(True, positive=True),
    "velocity_range": _triple(True, positive=True),
    "slip_std": _triple(True),
    "slip_cov": _slip_cov,
    "big_slip_prob": _prob,
    "big_slip_std": _triple(True),
    "pan_amplitude": lambda k, v: _angle_range(k, v, math.pi),
    "pan_period": _positive,
    "fov": _fov,
    "range_mm": _range_mm,
    "detect_prob": _prob,
    "focal_px": _positive,
    "beacon_height_mm": _positive,
    "sensor_curve": _sensor_curve,
    "noise": _choice(tuple(NOISE_PRESETS)),
    "sigma_height": _sigma,
    "sigma_angle": _sigma,
    "walls": _choice(WALL_MODES),
    "robot_radius": _positive,
    "pymunk_substeps": _int_min(1),
    "effects": lambda k, v: validate_effects(v),
    "reward": _choice(REWARDS),
    "reward_weights": _reward_weights,
    "start_pose": _start_pose,
}


def check_field_fit(cfg: dict[str, Any]) -> None:
    """The checks of ``start_pose`` and ``robot_radius`` against ``field`` (both envs), each only where it
    matters: a fixed start inside the field unless ``walls="open"`` (no walls, the episode goes on off the
    field, so a start off it is a valid pose); ``robot_radius`` below half the field width only for
    ``walls="pymunk"`` (the only mode with a robot body); a field wider than the ``START_MARGIN_MM`` margin
    of ``start_pose="random"``."""
    half_l, half_w = cfg["field"][0] / 2, cfg["field"][1] / 2
    sp = cfg["start_pose"]
    if cfg["walls"] != "open" and isinstance(sp, list) and (abs(sp[0]) > half_l or abs(sp[1]) > half_w):
        raise _bad("start_pose", sp, f"a position inside the field |x| <= {half_l:g}, |y| <= {half_w:g} "
                   f"with walls={cfg['walls']!r} (only walls='open' starts off the field)")
    if cfg["walls"] == "pymunk" and cfg["robot_radius"] >= min(half_l, half_w):
        raise _bad("robot_radius", cfg["robot_radius"], f"a radius < {min(half_l, half_w):g} mm (half the field width) "
                   "with walls='pymunk'")
    if sp == "random" and min(half_l, half_w) <= START_MARGIN_MM:
        raise _bad("start_pose", sp, f"a fixed pose: the field is too small for a {START_MARGIN_MM:g} mm margin")


def make_config(config: dict[str, Any] | None = None) -> dict[str, Any]:
    """Merge ``config`` into :func:`default_config`, validate, and return the full normalized dict.

    Nested dicts are merged (a user dict updates the default dict). Lists are replaced.
    Raises ValueError naming the key and the valid choices on an unknown key or a bad value.
    """
    cfg = merge_config(default_config(), config)
    out = {key: CHECKS[key](key, value) for key, value in cfg.items()}
    check_field_fit(out)
    out["effects"] = finalize_effects(out["effects"], out)
    return out


def merge_config(cfg: dict[str, Any], config: dict[str, Any] | None, whole: tuple[str, ...] = ()) -> dict[str, Any]:
    """``cfg`` (a fresh dict of defaults) updated with the user's ``config``, unvalidated: nested dicts
    merged, except those of the keys in ``whole`` (a dict whose entries only mean something together, e.g.
    a sensor curve's basis and coef), anything else replaced (deep copies). An unknown key raises ValueError
    naming the valid keys."""
    if config is None:
        config = {}
    if not isinstance(config, dict):
        raise ValueError(f"config must be a dict, got {type(config).__name__}")
    for key, value in config.items():
        if key not in cfg:
            raise ValueError(f"unknown config key '{key}' (valid keys: {', '.join(sorted(cfg))})")
        if isinstance(cfg[key], dict) and isinstance(value, dict) and key not in whole:
            merged = copy.deepcopy(cfg[key])
            merged.update(value)
            value = merged
        cfg[key] = copy.deepcopy(value)
    return cfg


def check_reset_options(options: Any, checks: dict[str, Callable[[Any], Any]]) -> dict[str, Any]:
    """``reset(options=...)`` validated: None (no options) or a dict of the env's options, ``checks``
    {option name: check of its value}; returns {name: checked value} for every option, None for those not
    given. A non-dict, an unknown option or a bad value raises a one-line ValueError naming the option."""
    valid = ", ".join(map(repr, checks))
    if options is None:
        options = {}
    if not isinstance(options, dict):
        raise ValueError(f"reset options must be None or a dict, got {type(options).__name__} (valid options: {valid})")
    for name in options:
        if name not in checks:
            raise ValueError(f"unknown reset option {name!r} (valid options: {valid})")
    return {name: None if options.get(name) is None else check(options[name]) for name, check in checks.items()}


def option_array(name: str, value: Any, kinds: str, want: str) -> np.ndarray:
    """Reset option ``name``'s ``value`` as a non-empty 1-d NumPy array of a dtype kind in ``kinds`` (e.g.
    ``"iuf"`` numbers, ``"bi"`` booleans or integers), else a one-line ValueError naming the option and ``want``."""
    try:
        a = np.asarray(value)
    except (ValueError, TypeError):  # ragged nested lists
        a = None
    if a is None or a.ndim != 1 or a.size == 0 or a.dtype.kind not in kinds:
        got = type(value).__name__ if a is None or a.dtype.kind in "OSU" else f"shape {a.shape}, dtype {a.dtype}"
        raise ValueError(f"reset option {name!r}: expected {want}, got {got}")
    return a


def sensor_sigmas(cfg: dict[str, Any]) -> tuple[float, float]:
    """(sigma_height px, sigma_angle rad) of a validated config: the preset, overridden if set."""
    preset = NOISE_PRESETS[cfg["noise"]]
    sh = preset["sigma_height"] if cfg["sigma_height"] is None else cfg["sigma_height"]
    sa = preset["sigma_angle"] if cfg["sigma_angle"] is None else cfg["sigma_angle"]
    return float(sh), float(sa)
