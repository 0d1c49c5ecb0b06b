"""``WheeledRobot-v0``: a velocity-commanded robot with a range/bearing camera among known landmarks."""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.error import ResetNeeded

from aibo_core.features import FEATURE_MAPS

from ..camera import MeanHeight, sight_range
from ..config import check_reset_options, option_array
from ..context import NO_COMMAND, Frame, Motion, Sighting, wrap_angle
from ..effects import EffectChain
from ..robot import draw_start, move
from ..walls import make_walls
from ..wheeled_config import make_config, true_weights

RANGE_BOUND_MM = 1.0e6  # observation bound for a range; raw values are in info
WALL_CONTACT_TOL_MM = 1e-6  # the walls moved the robot by more than this: a wall contact
SLOT = 4  # observation numbers per sighting: landmark index, range, bearing, seen flag


class WheeledRobotEnv(gym.Env):
    """A wheeled robot driven by velocity commands, with a range/bearing camera among known landmarks.

    The robot of the UTIAS MRCLAM logs (and of any velocity-commanded robot): each frame (``dt`` = 0.1 s)
    it holds a continuous command, e.g. (v mm/s, omega rad/s); its camera, fixed on the heading, may
    take an image and report every landmark it recognizes in it (range and bearing). Its true action
    model (the velocity a command really gives) is hidden: learning it from a log is the task.

    ## Action space

    ``Box(float64, shape=(k,))``, k = ``len(control_names)`` (default 2: [v mm/s, omega rad/s]),
    bounds ``control_low`` .. ``control_high`` (default [-300, -1.5] .. [300, 1.5]). The true velocity
    (vx mm/s, vy mm/s, vtheta rad/s, robot frame) of a command c is ``features(c) @ weights``, with the
    feature map ``feature_map`` of :mod:`aibo_core.features` (``diff_drive``: [v, omega, v|omega|,
    |omega|, 1]; ``linear``: [c_1, ..., c_k, 1]) and the config's ``weights`` (F x 3). Actions outside
    the space raise ValueError.

    ## Observation space

    ``Box(float32, shape=(4 K + k,))``: K sighting slots (K = ``env.max_sightings``: the number of
    landmarks B, doubled by ``false_sightings``), then the last command. What the robot knows onboard:

    ============  ====================================  ==========================================
    index         meaning                               range
    ============  ====================================  ==========================================
    4j            slot j: landmark index                [-1, B-1]; -1 when the slot is unused
    4j+1          slot j: measured range, mm            [-1e6, 1e6] (clipped); 0 when unused
    4j+2          slot j: measured bearing from the     [-pi, pi] rad, CCW positive; 0 when unused
                  heading
    4j+3          slot j: seen flag                     {0, 1}
    4K .. 4K+k-1  the command of the last step          [min(low, 0), max(high, 0)]; 0 after reset
    ============  ====================================  ==========================================

    Slots are filled in report order (``info["sightings"]``); the reset observation has none.

    ## Info

    Every key has the same type and shape on every step (vector envs stack them; nothing is None):

    ================  ===============================================  ===========================
    key               value                                            units
    ================  ===============================================  ===========================
    pose              ndarray float64 (3,): true pose after the step   mm, mm, rad in (-pi, pi]
    command           ndarray float64 (k,): the command executed       as ``control_names``
                      (zeros after reset)
    velocity          ndarray float64 (3,): its true velocity          mm/s, mm/s, rad/s
                      ``features @ weights`` (before the effects)
    image             bool: this frame took an image                   -
    wall_contact      bool: the walls changed this frame's move        -
    sightings         dict of K-row arrays                             see below
    ================  ===============================================  ===========================

    ``info["sightings"]``: ``count`` (int, rows in use), ``beacon`` (int64 (K,), landmark index, -1
    unused), ``range`` (float64 (K,), mm, unclipped, 0 unused), ``bearing`` (float64 (K,), rad from the
    heading, 0 unused), ``spurious`` (bool (K,), ground truth: a false sighting).

    ## Motion

    Robot-frame displacement per frame = velocity dt + L z (``motion_cov`` = L L^T, mm^2, rad^2; z 3
    standard normals), then the motion effects; new pose = pose + R(theta) disp (+ the effects'
    world-frame offset), then the walls (``walls``, default ``"open"``: none).

    ## Sensing

    In an image frame, every landmark within ``range_mm`` (and at least
    :data:`aibo_gym.camera.MIN_SIGHT_MM` = 1 mm away: the camera cannot see a landmark it stands on)
    and ``fov / 2`` of the heading is reported
    with probability ``detect_prob`` (or ``detect_by_distance``'s at its distance; times ``detect_by_angle``'s factor
    at its angle off the heading, at most 1), in landmark order:
    range = f(d) + N(0, sigma_range_mm^2), f the
    ``sensor_curve`` (default f(d) = d), bearing = wrap(true bearing + N(0, sigma_bearing^2)).
    A frame takes an image on schedule (every ``image_every``-th frame, each with probability
    ``image_prob``), or as ``reset(options={"images": mask})`` says: ``mask[t]`` (bool, one per step,
    e.g. the frames of a measured log that have a sighting) for step t, the schedule after the last.
    ``options`` is None or a dict whose only valid key is ``"images"`` (None: the schedule; else a
    non-empty 1-d array of booleans or 0/1); any other key, a non-dict or a bad value raises a one-line
    ValueError naming the option.
    The sightings are taken at the end of the frame (after the move).

    ## Effects

    ``config={"effects": {name: {param: value}}}`` (:mod:`aibo_gym.catalogue`), as in
    ``AiboBeacons-v0``. The sensing effects see the range in ``Sighting.height`` (the size measurement,
    mm here) and its noise-free value in ``Sighting.true_height``; ``Sighting.image_angle`` is the true
    bearing (the camera does not pan; ``Frame.head_pan`` is 0). ``Frame.command`` is the command as a
    tuple of k floats and ``Frame.velocity(command)`` its true velocity, so ``actuation_lag`` delays
    continuous commands and ``response_time`` low-passes them. For a wheeled robot: actuation_lag, response_time,
    floor_drift, velocity_fade, drift,
    angle_bias, height_bias (a range offset, mm), beacon_height_scale (a range scale per landmark),
    distance_dependent_noise, off_center_shrink, false_sightings; wall_contact needs walls.

    ## Rewards

    None: the reward is always 0 (the env makes logs; a task would wrap it).

    ## Starting state and episode end

    ``start_pose`` (default (0, 0, 0)) or ``"random"`` (uniform on ``field`` with a 500 mm margin,
    uniform heading). terminated: only with ``walls="none"``, on leaving the field; truncated: after
    ``max_steps`` frames (default 6000 = 10 min); the id is registered with the same
    ``max_episode_steps``.

    ## Arguments

    ``gym.make("aibo_gym:WheeledRobot-v0", config={...})``; every key in :mod:`aibo_gym.wheeled_config`
    (unknown keys or bad values raise a one-line ValueError naming the key). No render modes; the
    instance's ``metadata["render_fps"]`` is ``1 / dt`` (10 by default). ``step`` before the first
    ``reset`` raises ``gymnasium.error.ResetNeeded``.

    ## Seeding

    Everything random uses ``self.np_random`` from ``reset(seed=...)``: each frame draws exactly
    3 + 2B normals then B + 1 uniforms, whatever happens: normals 0-2 the motion noise, 3 + 2i and
    4 + 2i the range and bearing noise of landmark i; uniform i the detection of landmark i, uniform B
    the image. ``start_pose="random"`` draws 3 uniforms at reset. Effects draw from their own streams
    (:mod:`aibo_gym.effects`), so enabling one leaves the rest unchanged.
    """

    metadata = {"render_modes": [], "render_fps": 10}

    def __init__(self, config: dict[str, Any] | None = None, render_mode: str | None = None) -> None:
        if render_mode is not None:
            raise ValueError(f"render_mode {render_mode!r}: WheeledRobot-v0 has no render modes (valid choice: None)")
        self.config = cfg = make_config(config)
        self.render_mode = None
        self.dt = float(cfg["dt"])
        self.metadata = {**self.metadata, "render_fps": 1.0 / self.dt}  # frames per simulated second
        self._reset_done = False
        self.k = len(cfg["control_names"])
        self.weights = true_weights(cfg)
        self.weights.flags.writeable = False
        self._features = FEATURE_MAPS[cfg["feature_map"]][0]
        self._chol = np.linalg.cholesky(np.asarray(cfg["motion_cov"]))
        self.landmarks = np.asarray(cfg["beacons"], dtype=float)
        self.landmarks.flags.writeable = False
        self.n_landmarks = len(self.landmarks)
        self.range_curve = MeanHeight(cfg)
        self._sight_range = sight_range(cfg)
        self.walls = make_walls(cfg)
        self.effects = EffectChain(cfg, sensor_capacity=self.n_landmarks)
        self.max_sightings = self.effects.max_sightings
        self.action_space = spaces.Box(np.asarray(cfg["control_low"]), np.asarray(cfg["control_high"]), dtype=np.float64)
        self.observation_space = self._observation_space()
        self.pose = (0.0, 0.0, 0.0)
        self.start_pose = [0.0, 0.0, 0.0]
        self.steps = 0
        self.last_sightings: list[Sighting] = []
        self._images: np.ndarray | None = None
        self._episode = -1
        self._command: Any = NO_COMMAND
        self._previous_command: Any = NO_COMMAND
        self._command_start = 0

    def _observation_space(self) -> spaces.Box:
        k, b = self.max_sightings, self.n_landmarks
        low_c = np.minimum(self.action_space.low, 0.0)
        high_c = np.maximum(self.action_space.high, 0.0)
        low = np.concatenate([np.tile([-1.0, -RANGE_BOUND_MM, -np.pi, 0.0], k), low_c])
        high = np.concatenate([np.tile([b - 1.0, RANGE_BOUND_MM, np.pi, 1.0], k), high_c])
        return spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        opts = check_reset_options(options, {"images": self._check_images})
        super().reset(seed=seed)
        self._reset_done = True
        self._episode = 0 if seed is not None else self._episode + 1
        self.effects.reset(max(self.np_random_seed, 0), self._episode)
        x, y, th = draw_start(self.config, self.np_random)
        x, y = self.walls.reset(x, y)
        self.pose = (x, y, wrap_angle(th))
        self.start_pose = list(self.pose)
        self.steps = 0
        self._images = opts["images"]
        self.last_sightings = []
        self._command, self._previous_command, self._command_start = NO_COMMAND, NO_COMMAND, 0
        zeros = np.zeros(self.k)
        return self._observation([], zeros), self._info([], zeros, np.zeros(3), False, False)

    def step(self, action):
        if not self._reset_done:
            raise ResetNeeded("WheeledRobot-v0: call reset() before step()")
        c = self._check_action(action)
        rng = self.np_random
        b = self.n_landmarks
        z = rng.standard_normal(3 + 2 * b)
        u = rng.random(b + 1)
        velocity = self.velocity_of(c)
        frame = self._frame(c)
        x, y, th = self.pose
        disp = velocity * self.dt + self._chol @ z[:3]
        m = Motion(disp, velocity.copy())
        if frame is not None and self.effects.motion_effects:
            m = self.effects.move(m, frame)
        nx, ny, nth = move(x, y, th, float(m.disp[0]), float(m.disp[1]), float(m.disp[2]))
        nx, ny = nx + float(m.world[0]), ny + float(m.world[1])
        cx, cy, left = self.walls.move(x, y, nx, ny, self.dt)
        contact = abs(cx - nx) + abs(cy - ny) > WALL_CONTACT_TOL_MM
        self.pose = (cx, cy, wrap_angle(nth))
        self.steps += 1
        image = self._image(u[b])
        sightings = self._sense(z[3:], u[:b], frame, contact) if image else []
        self.last_sightings = sightings
        obs = self._observation(sightings, c)
        info = self._info(sightings, c, velocity, contact, image)
        truncated = self.steps >= self.config["max_steps"]
        return obs, 0.0, bool(left), bool(truncated), info

    def render(self):
        gym.logger.warn("WheeledRobot-v0 has no render modes; render() returns None.")
        return None

    # ------------------------------------------------------------------ the robot
    def velocity_of(self, command: Any) -> np.ndarray:
        """(3,) true velocity (vx mm/s, vy mm/s, vtheta rad/s) of a command (k numbers): features @ weights."""
        return self._features(np.asarray(command, dtype=float).reshape(1, -1))[0] @ self.weights

    def _check_action(self, action: Any) -> np.ndarray:
        """``action`` as a (k,) float64 array; ValueError for anything ``action_space.contains`` rejects."""
        a = np.asarray(action, dtype=np.float64) if not isinstance(action, str) else None
        if a is None or a.shape != (self.k,) or not np.all(np.isfinite(a)) or not self.action_space.contains(a):
            sp = self.action_space
            raise ValueError(f"action {action!r}: not in the action space (k = {self.k} numbers "
                             f"{self.config['control_names']} within {sp.low.tolist()} .. {sp.high.tolist()})")
        return a

    def _frame(self, c: np.ndarray) -> Frame | None:
        """Track the command; the frame context for the effects (None without effects)."""
        command = tuple(float(v) for v in c)
        if command != self._command:
            self._previous_command, self._command, self._command_start = self._command, command, self.steps
        if not self.effects.effects:
            return None
        field = self.config["field"]
        return Frame(index=self.steps, time=self.steps * self.dt, dt=self.dt, command=command,
                     previous_command=self._previous_command, command_start=self._command_start,
                     pose_before=self.pose, pose_after=None, head_pan=0.0, wall_contact=False,
                     field=(field[0], field[1]), beacons=self.landmarks, velocities=np.zeros((0, 3)),
                     velocity_fn=self.velocity_of)

    # ------------------------------------------------------------------ the camera
    @staticmethod
    def _check_images(value: Any) -> np.ndarray:
        """Reset option ``images`` (not None): which steps take an image (bool, one per step); ValueError naming the
        option unless a non-empty 1-d array of booleans or of integers 0 / 1."""
        want = "a non-empty 1-d array of booleans (or 0 / 1), one per step"
        mask = option_array("images", value, "bi", want)
        if mask.dtype.kind == "i" and not np.isin(mask, (0, 1)).all():
            raise ValueError(f"reset option 'images': expected {want}, got integers other than 0 and 1")
        return mask.astype(bool)

    def _image(self, u: float) -> bool:
        """Does the frame just stepped (``self.steps`` - 1) take an image? The mask's, else the schedule's."""
        t = self.steps - 1
        if self._images is not None and t < len(self._images):
            return bool(self._images[t])
        cfg = self.config
        return (t + 1) % cfg["image_every"] == 0 and u < cfg["image_prob"]

    def _detect_prob(self, d: float, angle: float) -> float:
        """The probability that a landmark in view at distance ``d`` (mm) and ``angle`` (rad) off the heading is
        reported."""
        by_d, by_a = self.config["detect_by_distance"], self.config["detect_by_angle"]
        p = self.config["detect_prob"] if by_d is None else _interp(d, by_d)
        return p if by_a is None else min(1.0, p * _interp(abs(angle), by_a))

    def _sense(self, z: np.ndarray, u: np.ndarray, frame: Frame | None, contact: bool) -> list[Sighting]:
        """The sightings of the frame's end pose: every visible landmark detected, then the sensing effects."""
        cfg = self.config
        x, y, th = self.pose
        rmin, rmax = self._sight_range
        half_fov = 0.5 * cfg["fov"]
        sr, sb = cfg["sigma_range_mm"], cfg["sigma_bearing"]
        sightings = []
        for i, (bx, by) in enumerate(self.landmarks.tolist()):
            d = math.hypot(bx - x, by - y)
            bearing = wrap_angle(math.atan2(by - y, bx - x) - th)
            if rmin <= d <= rmax and abs(bearing) <= half_fov and u[i] < self._detect_prob(d, bearing):
                true_range = self.range_curve(d)
                sightings.append(Sighting(i, true_range + sr * float(z[2 * i]), wrap_angle(bearing + sb * float(z[2 * i + 1])),
                                          d, bearing, bearing, true_range))
        if frame is None:
            return sightings
        frame.pose_after, frame.wall_contact = self.pose, contact
        sightings = self.effects.sense(sightings, frame)
        for s in sightings:
            s.angle = wrap_angle(float(s.angle))
        return sightings

    # ------------------------------------------------------------------ outputs
    def _observation(self, sightings: list[Sighting], command: np.ndarray) -> np.ndarray:
        k = self.max_sightings
        obs = np.zeros(SLOT * k + self.k, dtype=np.float32)
        obs[0:SLOT * k:SLOT] = -1.0
        for j, s in enumerate(sightings):
            obs[SLOT * j:SLOT * j + SLOT] = (s.beacon, min(max(s.height, -RANGE_BOUND_MM), RANGE_BOUND_MM), s.angle, 1.0)
        obs[SLOT * k:] = command
        return np.clip(obs, self.observation_space.low, self.observation_space.high)

    def _info(self, sightings: list[Sighting], command: np.ndarray, velocity: np.ndarray, contact: bool,
              image: bool) -> dict[str, Any]:
        k = self.max_sightings
        beacon, rng_mm, bearing, spurious = np.full(k, -1, np.int64), np.zeros(k), np.zeros(k), np.zeros(k, bool)
        for j, s in enumerate(sightings):
            beacon[j], rng_mm[j], bearing[j], spurious[j] = s.beacon, s.height, s.angle, s.spurious
        return {
            "pose": np.array(self.pose),
            "command": np.array(command, dtype=float),
            "velocity": np.asarray(velocity, dtype=float).copy(),
            "image": bool(image),
            "wall_contact": bool(contact),
            "sightings": {"count": len(sightings), "beacon": beacon, "range": rng_mm, "bearing": bearing,
                          "spurious": spurious},
        }


def _interp(x: float, table: list[list[float]]) -> float:
    """The table's [[x, y], ...] value at ``x``: linear between its points, held beyond them."""
    return float(np.interp(x, [row[0] for row in table], [row[1] for row in table]))
