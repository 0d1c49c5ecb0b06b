"""``waypoints``: the driving policy of ``WheeledRobot-v0`` logs, as the MRCLAM robots drove.

The robot drives to random waypoints on the field (uniform, ``margin_mm`` from its edge): each leg
gets a cruise speed uniform in [``v_min_frac``, 1] x ``v_max_mm_s``; the turn rate is
``gain`` x heading error, clipped to +-``omega_max_rad_s``; the forward speed is the cruise speed
x cos(heading error), 0 when the waypoint is behind (turning on the spot). Each command is held for
``hold_s`` seconds (default 1 s). A waypoint within ``reach_mm`` ends the leg; with probability
``pause_prob`` the next leg is a stop of about 1-3 s (v = 0, omega = 0). Commands stay in
[0, v_max] x [-omega_max, omega_max] (defaults: MRCLAM's 86 mm/s and 0.57 rad/s).

Why the hold: a command recomputed every frame from the pose carries information about the pose's
noise that a learner treating commands as given cannot use; on 10-minute logs EM then learned the
turn gain 4% low (0.863 for 0.9 at ``hold_s`` = one frame, 0.91 on the same commands replayed open
loop; 0.893 with the 1 s hold). Real closed-loop robots have the same feedback.

It steers on the true pose (``info["pose"]``): a simulator's driver, whose commands are what the log
keeps. Its random choices come from its own seeded stream.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..context import wrap_angle

DEFAULTS: dict[str, float] = {"v_max_mm_s": 86.0, "omega_max_rad_s": 0.57, "v_min_frac": 0.3, "gain": 1.5,
                              "reach_mm": 300.0, "margin_mm": 500.0, "pause_prob": 0.1, "hold_s": 1.0}


def validate_waypoint_params(params: dict[str, Any] | None) -> dict[str, float]:
    """Defaults merged with ``params``; one-line ValueError naming an unknown or bad parameter."""
    out = dict(DEFAULTS)
    for key, value in (params or {}).items():
        if key not in DEFAULTS:
            raise ValueError(f"policy 'waypoints': unknown parameter '{key}' (valid parameters: {', '.join(sorted(DEFAULTS))})")
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or not value >= 0 \
                or not math.isfinite(value):
            raise ValueError(f"policy 'waypoints': parameter '{key}' must be a finite number >= 0, got {value!r}")
        out[key] = float(value)
    if not 0 <= out["v_min_frac"] <= 1 or not 0 <= out["pause_prob"] <= 1:
        raise ValueError("policy 'waypoints': parameters 'v_min_frac' and 'pause_prob' must be in [0, 1]")
    return out


class WaypointDriver:
    """Random-waypoint driving (module docstring): ``reset(info)`` then ``act(obs, info) -> [v, omega]``."""

    name = "waypoints"

    def __init__(self, config: dict[str, Any], seed: int, **params: Any) -> None:
        self.params = validate_waypoint_params(params)
        self.dt = float(config["dt"])
        half = np.asarray(config["field"], float) / 2 - self.params["margin_mm"]
        self.half = np.maximum(half, 0.0)
        self.rng = np.random.default_rng([int(seed), 0x77617970])  # "wayp"
        self.goal = np.zeros(2)
        self.cruise = 0.0
        self.pause_left = 0
        self.hold = max(1, int(round(self.params["hold_s"] / self.dt)))
        self.command = np.zeros(2)
        self.held = 0

    def reset(self, info: dict[str, Any]) -> None:
        self._new_leg()
        self.held = 0

    def _new_leg(self) -> None:
        p = self.params
        self.goal = self.rng.uniform(-self.half, self.half)
        self.cruise = p["v_max_mm_s"] * self.rng.uniform(p["v_min_frac"], 1.0)
        pause = self.rng.uniform(1.0, 3.0)  # s
        self.pause_left = max(1, round(pause / (self.dt * self.hold))) if self.rng.random() < p["pause_prob"] else 0

    def act(self, obs: np.ndarray, info: dict[str, Any]) -> np.ndarray:
        """The held command, or a new one every ``hold_s`` seconds."""
        if self.held <= 0:
            self.command, self.held = self._steer(info), self.hold
        self.held -= 1
        return self.command.copy()

    def _steer(self, info: dict[str, Any]) -> np.ndarray:
        if self.pause_left > 0:
            self.pause_left -= 1
            return np.zeros(2)
        x, y, th = info["pose"]
        if math.hypot(self.goal[0] - x, self.goal[1] - y) < self.params["reach_mm"]:
            self._new_leg()
            return self._steer(info)
        err = wrap_angle(math.atan2(self.goal[1] - y, self.goal[0] - x) - th)
        w_max = self.params["omega_max_rad_s"]
        omega = min(max(self.params["gain"] * err, -w_max), w_max)
        v = self.cruise * max(0.0, math.cos(err))
        return np.array([v, omega])
