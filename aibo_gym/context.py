"""What the simulator's effects see and change: one frame's context, its motion, its sightings.

Units: mm, rad, px, s. Robot frame: x forward, y left, theta counter-clockwise.

* :class:`Frame`: the context of one ``step`` (time, commands, poses, head pan, walls, geometry),
  passed to every effect hook; read it, do not change it.
* :class:`Motion`: the motion of one frame, which motion hooks may change.
* :class:`Sighting`: one reported sighting with its ground truth, which sensing hooks may change,
  drop, or create.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np


def wrap_angle(a: float) -> float:
    """Angle wrapped to (-pi, pi], rad."""
    r = math.remainder(a, 2.0 * math.pi)
    return math.pi if r <= -math.pi else r


NO_COMMAND = -1  # Frame.previous_command before the first command: the robot was at rest


@dataclass(slots=True)
class Frame:
    """The context of one frame (one ``env.step``).

    index: frames stepped since reset before this one (0 on the first step).
    time: s, ``index * dt``: the elapsed time at the start of the frame.
    dt: s per frame.
    command: the command of this frame: an action index 0..39 (``AiboBeacons-v0``) or, for continuous
        commands (``WheeledRobot-v0``), a tuple of k floats (e.g. (v mm/s, omega rad/s)).
    previous_command: the command in force before ``command`` started (``NO_COMMAND`` = -1 when
        ``command`` has run since reset: before it the robot stood still).
    command_start: frame index at which ``command`` started (consecutive equal actions are one command).
    pose_before: (x mm, y mm, theta rad) at the start of the frame.
    pose_after: (x mm, y mm, theta rad) at the end of the frame, after the walls; None during the
        motion hooks, set before the sensing hooks.
    head_pan: rad relative to the body, at the end of the frame (when the sighting is taken).
    wall_contact: True when the walls changed this frame's move (set before the sensing hooks;
        False during the motion hooks).
    field: (length x, width y) mm, origin at the centre.
    beacons: (B, 2) beacon positions, mm.
    velocities: (40, 3) true velocities of the actions (mm/s, mm/s, rad/s, robot frame); (0, 3) for
        continuous commands.
    velocity_fn: for continuous commands, the true velocity (3,) of a command (a tuple of k floats);
        None for discrete ones (``velocities`` is their table). Use :meth:`velocity` for either.
    """

    index: int
    time: float
    dt: float
    command: int
    previous_command: int
    command_start: int
    pose_before: tuple[float, float, float]
    pose_after: tuple[float, float, float] | None
    head_pan: float
    wall_contact: bool
    field: tuple[float, float]
    beacons: np.ndarray
    velocities: np.ndarray
    velocity_fn: Callable[[Any], np.ndarray] | None = None

    def velocity(self, command: Any) -> np.ndarray:
        """(3,) true velocity (mm/s, mm/s, rad/s, robot frame) of ``command`` (an index or a tuple of k floats)."""
        if self.velocity_fn is not None:
            return self.velocity_fn(command)
        return self.velocities[command]

    @property
    def since_command(self) -> float:
        """Seconds since the current command started, at the start of this frame."""
        return (self.index - self.command_start) * self.dt


@dataclass(slots=True)
class Motion:
    """The motion of one frame: new pose = pose + R(theta) disp + (world, 0), then the walls.

    disp: ndarray (3,) robot-frame displacement (mm, mm, rad), slip noise included; it equals
        ``velocity * dt`` + slip.
    velocity: ndarray (3,) the true velocity driving ``disp`` (mm/s, mm/s, rad/s); change it with
        :meth:`set_velocity` so that ``disp`` follows.
    world: ndarray (2,) world-frame offset added after the rotation (mm, mm).
    command: the command driving ``velocity`` when an effect replaced the frame's own (``actuation_lag``: the
        delayed one, for an effect after it to read); None: ``Frame.command``.
    """

    disp: np.ndarray
    velocity: np.ndarray
    world: np.ndarray = field(default_factory=lambda: np.zeros(2))
    command: Any = None

    def set_velocity(self, velocity: np.ndarray, dt: float) -> None:
        """Replace the driving velocity (mm/s, mm/s, rad/s), keeping the slip noise of ``disp``."""
        velocity = np.asarray(velocity, dtype=float)
        self.disp = self.disp + (velocity - self.velocity) * dt
        self.velocity = velocity


@dataclass(slots=True)
class Sighting:
    """One sighting as reported, with its ground truth.

    beacon: index of the beacon reported (for a spurious sighting: the label it was given).
    height: px, as measured (noise and effects included).
    angle: rad, as measured: bearing from the body heading, counter-clockwise, in (-pi, pi].
    distance: mm, true distance to the beacon (NaN for a spurious sighting).
    bearing: rad, true bearing from the body heading (for a spurious sighting: where it appears).
    image_angle: rad, true position in the image: ``bearing - head_pan`` wrapped (0 = centre).
    true_height: px, the noise-free height the beacon casts (NaN for a spurious sighting).
    spurious: True when no beacon is there (a false sighting).
    """

    beacon: int
    height: float
    angle: float
    distance: float
    bearing: float
    image_angle: float
    true_height: float
    spurious: bool = False
