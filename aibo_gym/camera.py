"""The robot's scanning head and camera: which beacon is seen and what the sighting reads.

* Head pan (rad, relative to the body): ``pan_amplitude * sin(2 pi t / pan_period)``, t in s.
* A beacon is *visible* when its bearing relative to the camera axis (heading + pan) is within
  ``fov / 2`` and its distance is within ``range_mm`` and at least :data:`MIN_SIGHT_MM`. At most one sighting per frame: the visible
  beacon nearest the image centre, detected with probability ``detect_prob``.
* Sighting: height px = ``focal_px * beacon_height_mm / d`` + N(0, sigma_height^2) (pinhole,
  57000 / d by default; config ``sensor_curve`` replaces the pinhole, see :class:`MeanHeight`) and
  angle rad = wrap(bearing from the body heading + N(0, sigma_angle^2)), counter-clockwise positive.
"""

from __future__ import annotations

import math
from typing import Any

from .context import Sighting, wrap_angle

MIN_SIGHT_MM = 1.0
"""The smallest distance (mm) at which a camera sees a landmark, whatever ``range_mm`` says: one closer (the
robot stands on it) is not seen, in both envs. Its bearing is undefined at 0 and a size curve in 1/d blows up."""


def sight_range(cfg: dict[str, Any]) -> tuple[float, float]:
    """(min, max) distance (mm) at which a landmark is seen: the config's ``range_mm``, its min raised to
    :data:`MIN_SIGHT_MM`."""
    rmin, rmax = cfg["range_mm"]
    return max(float(rmin), MIN_SIGHT_MM), float(rmax)


def head_pan(t: float, amplitude: float, period: float) -> float:
    """Head pan angle (rad, relative to the body) at time ``t`` (s)."""
    return amplitude * math.sin(2.0 * math.pi * t / period)


class MeanHeight:
    """The true (noise-free) beacon height px as a function of distance d (mm): the pinhole
    ``focal_px * beacon_height_mm / d``, or the config's ``sensor_curve`` (sum c_k d^k for ``power``,
    sum c_k d^-k for ``inverse``), e.g. a learned sensor model in a calibrated simulator.
    A plain class, so that envs pickle."""

    def __init__(self, cfg: dict[str, Any]) -> None:
        curve = cfg.get("sensor_curve")
        self.k = cfg["focal_px"] * cfg["beacon_height_mm"] if curve is None else 0.0
        self.coef = None if curve is None else [float(c) for c in curve["coef"]]
        self.sign = 1 if curve is None or curve["basis"] == "power" else -1

    def __call__(self, d: float) -> float:
        if self.coef is None:
            return self.k / d
        return sum(c * d ** (self.sign * i) for i, c in enumerate(self.coef))


class Camera:
    """Beacon sensing for one config; pure Python floats (4 beacons are faster than NumPy)."""

    def __init__(self, cfg: dict[str, Any], sigma_height: float, sigma_angle: float) -> None:
        self.beacons = [(float(b[0]), float(b[1])) for b in cfg["beacons"]]
        self.half_fov = 0.5 * cfg["fov"]
        self.rmin, self.rmax = sight_range(cfg)
        self.detect_prob = cfg["detect_prob"]
        self.mean_height = MeanHeight(cfg)
        self.sigma_height = sigma_height
        self.sigma_angle = sigma_angle

    def nearest_visible(self, x: float, y: float, theta: float, pan: float) -> tuple[int, float, float] | None:
        """The visible beacon nearest the image centre: (index, distance mm, bearing rad from
        the body heading), or None. ``theta`` is the heading, ``pan`` the head pan (rad)."""
        best = None
        best_off = math.inf
        for i, (bx, by) in enumerate(self.beacons):
            dx, dy = bx - x, by - y
            d = math.hypot(dx, dy)
            if not self.rmin <= d <= self.rmax:
                continue
            bearing = wrap_angle(math.atan2(dy, dx) - theta)
            off = abs(wrap_angle(bearing - pan))
            if off <= self.half_fov and off < best_off:
                best, best_off = (i, d, bearing), off
        return best

    def sight(
        self, x: float, y: float, theta: float, pan: float, u: float, z_height: float, z_angle: float
    ) -> Sighting | None:
        """One frame's sighting, or None; ``theta`` the heading, ``pan`` the head pan (rad).

        ``u`` ~ U(0, 1) decides detection; ``z_height``, ``z_angle`` ~ N(0, 1) are the noises.
        """
        seen = self.nearest_visible(x, y, theta, pan)
        if seen is None or u >= self.detect_prob:
            return None
        i, d, bearing = seen
        true_height = self.mean_height(d)
        height = true_height + self.sigma_height * z_height
        angle = wrap_angle(bearing + self.sigma_angle * z_angle)
        return Sighting(i, height, angle, d, bearing, wrap_angle(bearing - pan), true_height)
