"""Simulator twins of the effect catalogue. Names and parameter names are a contract.

Every effect is neutral at its defaults (an exact no-op: the same seed gives the same numbers as
without it). The residual signature of an effect is the variable on which the residuals of a model
that lacks it depend; a learner-side twin looks for it there.

=========================  ================================================  ==============================
name                       parameters (units)                                residual signature
=========================  ================================================  ==============================
actuation_lag              lag_s (s)                                         time since the last command change
response_time              tau_s (s, first-order lag of the command)         time since the last command change
floor_drift                drift_mm_s ([x, y] mm/s, world frame)             world heading
velocity_fade              fade_per_min (fraction of speed lost per minute)  elapsed time
wall_contact               (none)                                            distance to the walls
angle_bias                 bias_rad (rad)                                    none: a constant bearing offset
beacon_height_scale        scale (one factor per beacon)                     beacon identity
landmark_bearing_offset    offset_rad (rad, one per beacon)                  beacon identity (the bearings)
off_center_shrink          k (height x (1 - k phi^2), phi rad in the image)  position in the image
distance_dependent_noise   exponent (sigma ~ (d / 2500 mm)^exponent)         distance (the height variance)
false_sightings            rate (fraction of sightings, <= 0.5)              none: outliers anywhere in the image
heavy_tailed_noise         rate (fraction of sightings, <= 0.5), scale        none: heavier tails of both residuals
                           (factor on their noise's deviation, 1-10)
turn_dependent_noise       gain_s (s/rad: slip covariance x (1 + (gain_s       the spread of the bearing residuals
                           omega)^2), omega the turn rate)                   against the turn rate
turn_heading_noise         gain_s (s/rad: heading slip sd x sqrt(1 +           the spread of the bearing residuals
                           (gain_s omega)^2); forward, lateral unchanged)    against the turn rate
landmark_bias              sigma_rel (stationary std, fraction), tau_s (s)   size residuals correlated in time,
                                                                             per landmark
landmark_bearing_bias      sigma_rad (stationary std, rad), tau_s (s)        bearing residuals correlated in
                                                                             time, per landmark
=========================  ================================================  ==============================

Physical effects on heights (height scale, off-centre shrink, distance noise, landmark bias) act on the beacon's
true height and leave the pixel noise additive; they leave spurious sightings alone. Camera
calibration effects (``height_bias``, ``angle_bias``) act on every sighting.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

import numpy as np

from .camera import MeanHeight
from .context import NO_COMMAND, Frame, Motion, Sighting, wrap_angle
from .effects import Effect, register_effect

REFERENCE_DISTANCE_MM = 2500.0  # distance_dependent_noise: the noise equals the preset sigma here


@register_effect
class ActuationLag(Effect):
    """A new command takes effect only after ``lag_s`` (s); the previous one continues until then.

    The executed command of frame t is the one commanded at frame t - n, n = ceil(lag_s / dt) frames, for
    discrete commands (an index); a continuous one (a tuple of k floats, its velocity through
    ``Frame.velocity``) is the held command signal delayed by lag_s and averaged over the frame: with
    lag_s = (n + a) dt, 0 <= a < 1, (1 - a) c[t - n] + a c[t - n - 1] (the learner's twin does the same). The
    robot stands still until its first command takes effect. Slip noise is unchanged.
    Residual signature: time since the last command change.
    """

    name = "actuation_lag"
    defaults = {"lag_s": 0.0}
    bounds = {"lag_s": (0.0, math.inf)}

    def reset(self, rng: np.random.Generator) -> None:
        super().reset(rng)
        self.history: deque = deque()  # commands: indices or tuples of floats

    def motion(self, m: Motion, frame: Frame) -> Motion:
        frames = self.params["lag_s"] / frame.dt
        continuous = isinstance(frame.command, tuple)
        n = math.floor(frames + 1e-9) if continuous else math.ceil(frames - 1e-9)
        a = frames - n if continuous and frames - n > 1e-9 else 0.0
        if n == 0 and a == 0.0:
            return m
        self.history.append(frame.command)
        while len(self.history) > n + 2:
            self.history.popleft()
        executed = self._delayed(n)
        if a > 0.0 and not _no_command(executed):
            earlier = self._delayed(n + 1)
            earlier = executed if _no_command(earlier) else earlier
            executed = tuple((1.0 - a) * x + a * y for x, y in zip(executed, earlier))
        if executed != frame.command:
            v = np.zeros(3) if _no_command(executed) else frame.velocity(executed)
            m.set_velocity(v, frame.dt)
            m.command = executed
        return m

    def _delayed(self, n: int):
        """The command given n frames before this one (``NO_COMMAND`` before the first)."""
        return self.history[-1 - n] if len(self.history) > n else NO_COMMAND


@register_effect
class ResponseTime(Effect):
    """The robot follows its command through a first-order lag: a step in the command is reached as
    1 - exp(-t / ``tau_s``) (s), as a drive whose speed controller cannot change the speed at once (motor and body
    inertia, a speed ramp).

    A continuous command (a tuple of k floats) is low-passed, y[t] = y[t - 1] + a (c[t] - y[t - 1]) with
    a = 1 - exp(-dt / tau_s), y starting at the first command, and the frame moves at ``Frame.velocity(y[t])``
    (the learner's twin does the same, after ``actuation_lag`` when both act: it reads ``Motion.command``). A
    discrete command (an index, which cannot be averaged) has its true velocity low-passed the same way; the
    learner fits the effect on continuous commands only. Slip noise is unchanged.
    Residual signature: time since the last command change (as a lag's).
    """

    name = "response_time"
    defaults = {"tau_s": 0.0}
    bounds = {"tau_s": (0.0, math.inf)}
    motion_order = 1  # after actuation_lag, whatever the config's order: it follows the delayed command

    def reset(self, rng: np.random.Generator) -> None:
        super().reset(rng)
        self.state: np.ndarray | None = None  # the low-passed command (continuous) or velocity (discrete)

    def motion(self, m: Motion, frame: Frame) -> Motion:
        tau = self.params["tau_s"]
        if tau <= 0.0:
            return m
        command = frame.command if m.command is None else m.command
        continuous = isinstance(command, tuple)
        if not continuous and _no_command(command):
            return m  # before the first command acts (a lag): standing still, nothing to follow yet
        target = np.asarray(command, float) if continuous else np.asarray(m.velocity, float)
        a = 1.0 - math.exp(-frame.dt / tau)
        self.state = target.copy() if self.state is None else self.state + a * (target - self.state)
        if continuous:
            m.command = tuple(float(x) for x in self.state)
            m.set_velocity(frame.velocity(m.command), frame.dt)
        else:
            m.set_velocity(self.state, frame.dt)
        return m


def _no_command(command) -> bool:
    """True for ``NO_COMMAND`` (the index -1; a continuous command is a tuple, never equal to it)."""
    return not isinstance(command, tuple) and command == NO_COMMAND


@register_effect
class FloorDrift(Effect):
    """A sloped or grained floor: a constant world-frame drift ``drift_mm_s`` ([x, y] mm/s).

    Each frame the pose moves by ``drift_mm_s * dt`` in the world frame, whatever the command.
    Residual signature: world heading (the robot-frame residual turns with the heading).
    """

    name = "floor_drift"
    defaults = {"drift_mm_s": [0.0, 0.0]}

    def motion(self, m: Motion, frame: Frame) -> Motion:
        drift = self.params["drift_mm_s"]
        if drift[0] or drift[1]:
            m.world = m.world + np.asarray(drift) * frame.dt
        return m


@register_effect
class VelocityFade(Effect):
    """A draining battery: every walking velocity shrinks linearly with elapsed time.

    velocity x max(0, 1 - fade_per_min * t / 60 s), t = ``frame.time`` (s at the frame's start);
    ``fade_per_min`` is the fraction of speed lost per minute (negative, down to -1: a speed that grows, as the
    learner twin may fit it and its calibrated simulator then replays it). Slip noise is unchanged.
    Residual signature: elapsed time.
    """

    name = "velocity_fade"
    defaults = {"fade_per_min": 0.0}
    bounds = {"fade_per_min": (-1.0, math.inf)}

    def motion(self, m: Motion, frame: Frame) -> Motion:
        factor = max(0.0, 1.0 - self.params["fade_per_min"] * frame.time / 60.0)
        if factor != 1.0:
            m.set_velocity(m.velocity * factor, frame.dt)
        return m


@register_effect
class WallContact(Effect):
    """The walls stop the robot where a wall-free motion model would let it pass.

    In the simulator this is the wall model itself (``walls="clamp"`` or ``"pymunk"``), so the
    effect has no hook; enabling it with ``walls="none"`` is an error. ``Frame.wall_contact`` and
    ``info["wall_contact"]`` tell when the walls acted. Residual signature: distance to the walls.
    """

    name = "wall_contact"
    defaults: dict[str, Any] = {}

    @classmethod
    def finalize(cls, params: dict[str, Any], cfg: dict[str, Any]) -> dict[str, Any]:
        if cfg["walls"] in ("none", "open"):
            raise ValueError(f"effect 'wall_contact': needs config key 'walls' 'clamp' or 'pymunk', got {cfg['walls']!r}")
        return super().finalize(params, cfg)


@register_effect
class AngleBias(Effect):
    """A mis-mounted camera: a constant offset ``bias_rad`` (rad) in every observed bearing.

    Residual signature: none (a constant mean of the bearing residuals).
    """

    name = "angle_bias"
    defaults = {"bias_rad": 0.0}
    bounds = {"bias_rad": (-math.pi, math.pi)}

    def sense(self, sightings: list[Sighting], frame: Frame) -> list[Sighting]:
        bias = self.params["bias_rad"]
        if bias:
            for s in sightings:
                s.angle = wrap_angle(s.angle + bias)
        return sightings


@register_effect
class BeaconHeightScale(Effect):
    """Beacons differ in physical height: beacon i casts ``scale[i]`` times the nominal height.

    ``scale``: one factor per beacon (default all 1). Residual signature: beacon identity.
    """

    name = "beacon_height_scale"
    defaults = {"scale": []}
    per_beacon = {"scale": 1.0}
    bounds = {"scale": (1e-6, math.inf)}

    def sense(self, sightings: list[Sighting], frame: Frame) -> list[Sighting]:
        for s in sightings:
            f = self.params["scale"][s.beacon]
            if f != 1.0 and not s.spurious:
                s.height = s.height + (f - 1.0) * s.true_height
                s.true_height = f * s.true_height
        return sightings


@register_effect
class LandmarkBearingOffset(Effect):
    """Each beacon is seen at a bearing offset of its own: ``offset_rad[i]`` (rad) is added to every observed
    bearing of beacon i (a marker's visible centre off its surveyed position).

    ``offset_rad``: one offset per beacon (default all 0). Spurious sightings are left alone.
    Residual signature: beacon identity (of the bearing residuals).
    """

    name = "landmark_bearing_offset"
    defaults = {"offset_rad": []}
    per_beacon = {"offset_rad": 0.0}
    bounds = {"offset_rad": (-math.pi, math.pi)}

    def sense(self, sightings: list[Sighting], frame: Frame) -> list[Sighting]:
        for s in sightings:
            offset = self.params["offset_rad"][s.beacon]
            if offset and not s.spurious:
                s.angle = wrap_angle(s.angle + offset)
        return sightings


@register_effect
class OffCenterShrink(Effect):
    """Lens falloff: the apparent height shrinks away from the image centre.

    height = true height x (1 - k phi^2) + noise, phi = ``Sighting.image_angle`` = bearing - head pan
    (rad). ``k`` >= 0 with 1 - k (fov/2)^2 > 0 (negative, down to -10: heights that grow away from the centre, as
    the learner twin may fit them). Residual signature: position in the image.
    """

    name = "off_center_shrink"
    defaults = {"k": 0.0}
    bounds = {"k": (-10.0, math.inf)}

    @classmethod
    def finalize(cls, params: dict[str, Any], cfg: dict[str, Any]) -> dict[str, Any]:
        limit = 1.0 / (0.5 * cfg["fov"]) ** 2
        if params["k"] >= limit:
            raise ValueError(f"effect 'off_center_shrink': parameter 'k' must be < {limit:.4g} "
                             f"(1 / (fov/2)^2, heights stay positive), got {params['k']!r}")
        return super().finalize(params, cfg)

    def sense(self, sightings: list[Sighting], frame: Frame) -> list[Sighting]:
        k = self.params["k"]
        for s in sightings:
            if k and not s.spurious:
                shrink = k * s.image_angle * s.image_angle
                s.height = s.height - shrink * s.true_height
                s.true_height = (1.0 - shrink) * s.true_height
        return sightings


@register_effect
class DistanceDependentNoise(Effect):
    """Height noise grows with distance: sigma_height(d) = sigma_height * (d / 2500 mm)^exponent.

    The preset (or configured) ``sigma_height`` holds at the reference distance 2500 mm
    (``REFERENCE_DISTANCE_MM``); the height's deviation from the true height is scaled, so no
    extra random draw is made. Residual signature: distance (the variance of the height residuals).
    """

    name = "distance_dependent_noise"
    defaults = {"exponent": 0.0}

    def sense(self, sightings: list[Sighting], frame: Frame) -> list[Sighting]:
        e = self.params["exponent"]
        for s in sightings:
            if e and not s.spurious:
                gain = (s.distance / REFERENCE_DISTANCE_MM) ** e
                s.height = s.true_height + (s.height - s.true_height) * gain
        return sightings


@register_effect
class FalseSightings(Effect):
    """A fraction ``rate`` of all sightings are spurious (no beacon there), ``rate`` <= 0.5.

    Each real sighting is joined, with probability rate / (1 - rate), by one spurious sighting in
    the same frame, before or after it at random: a beacon label uniform over the beacons, a
    position uniform in the image (``|image_angle|`` <= fov/2 around the head pan) and a height
    uniform over the heights of a beacon within ``range_mm`` (focal * H / d, with the nearer end at
    least a tenth of the farther). All from the effect's own stream. Residual signature: none (outliers anywhere in the image).
    """

    name = "false_sightings"
    defaults = {"rate": 0.0}
    bounds = {"rate": (0.0, 0.5)}

    def capacity(self, n: int) -> int:
        return 2 * n

    def sense(self, sightings: list[Sighting], frame: Frame) -> list[Sighting]:
        rate = self.params["rate"]
        if not rate:
            return sightings
        out: list[Sighting] = []
        for s in sightings:
            out.append(s)
            if not s.spurious and self.rng.random() < rate / (1.0 - rate):
                out.insert(len(out) - int(self.rng.random() < 0.5), self._spurious(frame))
        return out

    def _spurious(self, frame: Frame) -> Sighting:
        cfg = self.cfg
        h = MeanHeight(cfg)
        rmin, rmax = cfg["range_mm"]
        beacon = int(self.rng.integers(len(cfg["beacons"])))
        image_angle = float(self.rng.uniform(-0.5 * cfg["fov"], 0.5 * cfg["fov"]))
        lo, hi = sorted((h(rmax), h(max(rmin, 0.1 * rmax))))
        height = float(self.rng.uniform(lo, hi))
        bearing = wrap_angle(frame.head_pan + image_angle)
        return Sighting(beacon, height, bearing, math.nan, bearing, image_angle, math.nan, spurious=True)


@register_effect
class HeavyTailedNoise(Effect):
    """A share ``rate`` of the real sightings has its noise ``scale`` times wider (a scale mixture of two Gaussians).

    Each real sighting, with probability ``rate`` (the effect's own stream; one draw per real sighting), has its
    height's and its angle's deviation from their true values (the noise, and whatever an effect earlier in the
    config added) multiplied by ``scale``: a partly hidden or blurred landmark, a detection off its centre. Spurious
    sightings are left alone. Residual signature: none (heavier tails of the size and bearing residuals, and a
    narrower core, than one Gaussian's).
    """

    name = "heavy_tailed_noise"
    defaults = {"rate": 0.0, "scale": 1.0}
    bounds = {"rate": (0.0, 0.5), "scale": (1.0, 10.0)}

    def sense(self, sightings: list[Sighting], frame: Frame) -> list[Sighting]:
        rate, scale = self.params["rate"], self.params["scale"]
        if not rate or scale == 1.0:
            return sightings
        for s in sightings:
            if not s.spurious and self.rng.random() < rate:
                s.height = s.true_height + (s.height - s.true_height) * scale
                s.angle = wrap_angle(s.bearing + wrap_angle(s.angle - s.bearing) * scale)
        return sightings


@register_effect
class TurnDependentNoise(Effect):
    """A robot that turns slips more than one that drives straight: the frame's slip noise (the displacement's
    departure from ``velocity * dt``, big slips included) is multiplied by sqrt(1 + (``gain_s`` omega)^2), omega the
    turn rate (rad/s) of the frame's true velocity after every other motion effect (a lag, a fading battery): its
    covariance by 1 + (gain_s omega)^2, the odometry motion model of Thrun, Burgard & Fox (2005, section 5.4).
    Draws nothing: the slip is the env's own, scaled. Residual signature: the spread of the bearing residuals
    against the commanded turn rate.
    """

    name = "turn_dependent_noise"
    defaults = {"gain_s": 0.0}
    bounds = {"gain_s": (0.0, 100.0)}
    motion_order = 2  # after every effect that changes the velocity (response_time: 1), whatever the config's order

    def motion(self, m: Motion, frame: Frame) -> Motion:
        g = self.params["gain_s"]
        if g:
            nominal = m.velocity * frame.dt
            m.disp = nominal + (m.disp - nominal) * math.sqrt(1.0 + (g * float(m.velocity[2])) ** 2)
        return m


@register_effect
class TurnHeadingNoise(Effect):
    """A robot that turns slips more in its heading: the frame's heading slip (the heading's departure from ``velocity
    * dt``) is multiplied by sqrt(1 + (``gain_s`` omega)^2), omega the turn rate (rad/s) of the frame's true velocity
    after every other motion effect; the forward and lateral slip unchanged (what the MRCLAM robots' Vicon residuals
    show: docs/results.md, "Motion noise that grows with the turn"). Draws nothing. Residual signature: the spread of
    the bearing residuals against the commanded turn rate.
    """

    name = "turn_heading_noise"
    defaults = {"gain_s": 0.0}
    bounds = {"gain_s": (0.0, 100.0)}
    motion_order = 2  # after every effect that changes the velocity (as turn_dependent_noise)

    def motion(self, m: Motion, frame: Frame) -> Motion:
        g = self.params["gain_s"]
        if g:
            nominal = float(m.velocity[2]) * frame.dt
            m.disp = m.disp.copy()
            m.disp[2] = nominal + (m.disp[2] - nominal) * math.sqrt(1.0 + (g * float(m.velocity[2])) ** 2)
        return m


@register_effect
class LandmarkBias(Effect):
    """Each landmark's size measurement carries a slowly varying relative bias of its own.

    The size of every (real) sighting of landmark l is multiplied by (1 + b_l(t)): the true size is
    scaled and the measurement noise stays additive (as the other physical effects). b_l is a
    first-order Gauss-Markov process, independent across landmarks, with stationary standard
    deviation ``sigma_rel`` and correlation time ``tau_s`` (s): b_l ~ N(0, sigma_rel^2) at reset, then
    every frame b_l <- phi b_l + sigma_rel sqrt(1 - phi^2) w, phi = exp(-dt / tau_s), w ~ N(0, 1), one
    normal per landmark per frame from the effect's own stream (seen or not). Real range sensors
    show this: MRCLAM's range errors are a per-landmark, per-pass bias (lag-1 correlation 0.92-0.97).
    Residual signature: size residuals of one landmark correlated over seconds.
    """

    name = "landmark_bias"
    defaults = {"sigma_rel": 0.0, "tau_s": 10.0}
    bounds = {"sigma_rel": (0.0, 0.5), "tau_s": (1e-3, math.inf)}
    SIGMA = "sigma_rel"  # the name of the process' stationary standard deviation

    def reset(self, rng: np.random.Generator) -> None:
        super().reset(rng)
        self.bias: np.ndarray | None = None

    def _advance(self, frame: Frame) -> np.ndarray:
        """The biases at the end of this frame (one step of the process per call: once per frame)."""
        sigma, tau = self.params[self.SIGMA], self.params["tau_s"]
        if self.bias is None:
            self.bias = sigma * self.rng.standard_normal(len(frame.beacons))
        phi = math.exp(-frame.dt / tau)
        self.bias = phi * self.bias + sigma * math.sqrt(1.0 - phi * phi) * self.rng.standard_normal(len(self.bias))
        return self.bias

    def sense(self, sightings: list[Sighting], frame: Frame) -> list[Sighting]:
        if not self.params[self.SIGMA]:
            return sightings
        bias = self._advance(frame)
        for s in sightings:
            if not s.spurious:
                self._bias(s, float(bias[s.beacon]))
        return sightings

    def _bias(self, s: Sighting, b: float) -> None:
        """Sighting ``s`` of a landmark whose bias is ``b`` now: its size scaled by (1 + b)."""
        s.height = s.height + b * s.true_height
        s.true_height = (1.0 + b) * s.true_height


@register_effect
class LandmarkBearingBias(LandmarkBias):
    """Each landmark's bearing carries a slowly varying bias of its own (rad): the bearings' ``landmark_bias``.

    Every (real) sighting of landmark l is seen at its bearing + c_l(t) (rad), c_l a first-order Gauss-Markov process
    per landmark, independent across landmarks, with stationary standard deviation ``sigma_rad`` and correlation time
    ``tau_s`` (s), drawn as ``landmark_bias``' process (one normal per landmark per frame from the effect's own
    stream, seen or not). A fixed offset per landmark is ``landmark_bearing_offset``. Measured on MRCLAM's robots:
    3-6 mrad at 20-100 s (docs/results.md, "The bearings' bias states, scanned").
    Residual signature: bearing residuals of one landmark correlated over seconds.
    """

    name = "landmark_bearing_bias"
    defaults = {"sigma_rad": 0.0, "tau_s": 20.0}
    bounds = {"sigma_rad": (0.0, 0.5), "tau_s": (1e-3, math.inf)}
    SIGMA = "sigma_rad"

    def _bias(self, s: Sighting, b: float) -> None:
        """Sighting ``s`` of a landmark whose bias is ``b`` (rad) now: seen at its bearing + b."""
        s.angle = wrap_angle(s.angle + b)
