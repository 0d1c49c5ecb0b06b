"""The robot's body: its true action model and its motion per frame.

Each of the 40 actions (see :mod:`aibo_core.actions`) has a *true* velocity (vx mm/s, vy mm/s,
vtheta rad/s, robot frame) that differs from what the action attempts. It is drawn once from
``robot_seed`` (independent of any episode seed) by :func:`true_velocities`:

1. nominal velocities: attempted normalized velocities scaled per component so that the largest
   magnitude over the 40 actions is ``nominal_max`` (355 mm/s, 420 mm/s, pi/2 rad/s);
2. per-action, per-component gains ~ U(0.85, 1.15);
3. cross-coupling shared by all actions: turning drags the body sideways (vy += k_turn * vtheta),
   forward speed leaks into vy (vy += k_leak * vx) and bends the walk (vtheta += k_yaw * vx);
4. small per-action offsets ~ N(0, (8 mm/s, 8 mm/s, 0.03 rad/s));
5. each component rescaled so that its max - min over the 40 actions is ``velocity_range``
   (710 mm/s, 840 mm/s, pi rad/s, the ranges of the paper's simulation).

Config key ``velocities`` (40 x 3) replaces all of this.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from aibo_core.actions import attempted_velocities

from .config import START_MARGIN_MM, make_config
from .context import wrap_angle  # noqa: F401  (re-exported: its historical home)


def nominal_velocities(nominal_max: Any = (355.0, 420.0, math.pi / 2)) -> np.ndarray:
    """(40, 3) attempted velocities in mm/s, mm/s, rad/s: largest |value| per column = nominal_max."""
    att = attempted_velocities()
    return att / np.abs(att).max(axis=0) * np.asarray(nominal_max, dtype=float)


def _draw_true_velocities(cfg: dict[str, Any]) -> np.ndarray:
    rng = np.random.default_rng(cfg["robot_seed"])
    v = nominal_velocities(cfg["nominal_max"]) * rng.uniform(0.85, 1.15, size=(40, 3))
    k_turn = rng.uniform(40.0, 120.0) * rng.choice([-1.0, 1.0])  # mm of sideways drag per rad turned
    k_leak = rng.uniform(0.03, 0.10) * rng.choice([-1.0, 1.0])  # mm/s sideways per mm/s forward
    k_yaw = rng.uniform(-3e-4, 3e-4)  # rad per mm walked forward
    vx, vth = v[:, 0].copy(), v[:, 2].copy()
    v[:, 1] += k_turn * vth + k_leak * vx
    v[:, 2] += k_yaw * vx
    v += rng.normal(0.0, [8.0, 8.0, 0.03], size=(40, 3))
    span = v.max(axis=0) - v.min(axis=0)
    return v * (np.asarray(cfg["velocity_range"]) / span)


def true_velocities(config: dict[str, Any] | None = None) -> np.ndarray:
    """(40, 3) true velocities (mm/s, mm/s, rad/s) of the robot described by ``config``.

    Depends only on ``robot_seed``, ``nominal_max`` and ``velocity_range`` (or ``velocities``).
    """
    cfg = make_config(config)
    if cfg["velocities"] is not None:
        return np.asarray(cfg["velocities"], dtype=float)
    return _draw_true_velocities(cfg)


def draw_start(cfg: dict[str, Any], rng: np.random.Generator) -> tuple[float, float, float]:
    """The start pose (x mm, y mm, theta rad) of config ``start_pose``: the fixed pose, or for ``"random"``
    3 uniforms from ``rng``: on the field with a ``START_MARGIN_MM`` margin, any heading."""
    sp = cfg["start_pose"]
    if sp != "random":
        return float(sp[0]), float(sp[1]), float(sp[2])
    hl = 0.5 * cfg["field"][0] - START_MARGIN_MM
    hw = 0.5 * cfg["field"][1] - START_MARGIN_MM
    r = rng.uniform([-hl, -hw, -math.pi], [hl, hw, math.pi])
    return float(r[0]), float(r[1]), float(r[2])


def move(x: float, y: float, theta: float, dx: float, dy: float, dtheta: float) -> tuple[float, float, float]:
    """Pose after a robot-frame displacement (mm, mm, rad): pose + R(theta) disp (theta unwrapped)."""
    c, s = math.cos(theta), math.sin(theta)
    return x + c * dx - s * dy, y + s * dx + c * dy, theta + dtheta
