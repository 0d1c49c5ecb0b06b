"""``AiboBeacons-v0``: a simulated Sony Aibo walking on a 5.4 m x 3.6 m field with four beacons."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.error import ResetNeeded

from aibo_core.actions import N_ACTIONS, attempted_velocities

from ..camera import Camera, head_pan
from ..config import REWARD_TERMS, check_reset_options, make_config, option_array, sensor_sigmas
from ..context import NO_COMMAND, Frame, Motion, Sighting
from ..effects import EffectChain
from ..policies.onboard import OnboardTracker
from ..robot import draw_start, move, true_velocities, wrap_angle
from ..walls import make_walls

HEIGHT_BOUND_PX = 1000.0  # observation bound for the beacon height; raw values are in info
WALL_CONTACT_TOL_MM = 1e-6  # the walls moved the robot by more than this: a wall contact


class AiboBeaconsEnv(gym.Env):
    """A legged robot with a scanning camera, walking among known beacons (Stronger & Stone, IV).

    The robot executes one of 40 walk actions per frame (``dt`` = 1/30 s) and, with its head
    panning side to side, its camera reports at most one beacon per frame (effects may add more). Its true action model (the actual
    velocity of each action) is hidden; learning it, and the sensor model, from a log is the task.

    ## Action space

    ``Discrete(40)``: action ``8*i + j`` walks "as fast as possible" with normalized turn
    ``A_TURN[i]`` in {-1/2, -1/6, 0, 1/6, 1/2} and direction ``B_DIRECTION[j]`` in
    {0, pi/4, ..., -pi/4} (see :mod:`aibo_core.actions`). Its *true* velocity
    (:func:`aibo_gym.robot.true_velocities`, mm/s, mm/s, rad/s, robot frame) depends on ``robot_seed``.

    ## Observation space

    ``Box(float32, shape=(B + 7,))`` with B beacons (4 by default); what the robot knows onboard:

    =========  ===========================  ===========================================
    index      meaning                      range
    =========  ===========================  ===========================================
    0 .. B-1   one-hot of the beacon seen   {0, 1}; all 0 when none
    B          beacon height, px            [-1000, 1000] (clipped); 0 when none
    B+1        beacon angle from the body   [-pi, pi] rad, CCW positive; 0 when none
               heading
    B+2        seen flag                    {0, 1}
    B+3        head pan, rad (rel. body)    [-pi, pi]
    B+4..B+6   previous action's attempted  [-1, 1]; 0 after reset
               normalized (vx, vy, vtheta)
    =========  ===========================  ===========================================

    The sighting is taken at the end of the frame (after the move). The reset observation has no
    sighting. A beacon is seen within ``range_mm`` and ``fov / 2`` of the camera axis (:mod:`aibo_gym.camera`),
    never closer than :data:`aibo_gym.camera.MIN_SIGHT_MM` = 1 mm (the robot standing on it).

    The observation carries the frame's first sighting (row 0 of ``info["sightings"]``).

    ## Info

    Every key has the same type and shape on every step (vector envs stack them; nothing is None):

    ==================  ============================================  ==============================
    key                 value                                         units
    ==================  ============================================  ==============================
    pose                ndarray float64 (3,): true pose after step    mm, mm, rad in (-pi, pi]
    head_pan            float                                         rad, relative to the body
    action_velocity     ndarray float64 (3,): true velocity of the    mm/s, mm/s, rad/s
                        action executed (zeros after reset)
    wall_contact        bool: the walls changed this frame's move     -
    sightings           dict of K-row arrays, K = ``max_sightings``   see below
    rewards             dict of the reward terms (floats, the keys    see "Rewards"
                        of ``REWARD_TERMS`` on every step)
    ==================  ============================================  ==============================

    ``info["sightings"]``: ``count`` (int, 0..K: rows in use, in report order), ``beacon`` (int64 (K,),
    -1 in unused rows), ``height`` (float64 (K,), px, unclipped, 0 unused), ``angle`` (float64 (K,),
    rad from the body heading, 0 unused), ``spurious`` (bool (K,), ground truth: a false sighting).
    K is fixed per env: 1 without effects that create sightings (``env.max_sightings``).

    ## Motion

    Robot-frame displacement per frame = v dt + N(0, diag(slip_std^2)) (+ a large slip
    N(0, diag(big_slip_std^2)) with probability ``big_slip_prob``), then the motion effects;
    new pose = pose + R(theta) disp + (effects' world-frame offset), then the wall model (``walls``).

    ## Effects

    ``config={"effects": {name: {param: value}}}`` (:mod:`aibo_gym.effects`, catalogue in
    :mod:`aibo_gym.catalogue`): hooks on the motion and on the sightings, given a frame context.

    ## Rewards

    Named terms, highway-env style: ``info["rewards"]`` is a dict of floats with the same keys on
    every step (:data:`aibo_gym.config.REWARD_TERMS`), and the reward is
    ``sum(reward_weights[k] * info["rewards"][k])``. With ``reward="none"`` (the default) nothing is
    computed: every term and the reward are 0. With ``reward="explore"`` the terms are computed
    from what the robot knows onboard (its commands, its sightings and an onboard EKF:
    :class:`aibo_gym.policies.onboard.OnboardTracker`), never from the true pose:

    ===========  ===================================================================  =====================
    term         value of one frame                                                   sum over an episode
    ===========  ===================================================================  =====================
    balance      H_t - H_(t-1), H = entropy of the frames per command / log(40)       H at the end, [0, 1]
    coverage     new cells / 1920; cell = (command, distance bin of 6 over            share of cells seen
                 ``range_mm`` (distance = 57000 / height px), bearing bin of 8)
    sightings    sightings reported this frame                                        sightings
    wall         -clip(1 - e / 300 mm, 0, 1), e = distance of the onboard estimate    <= 0
                 to the nearest field edge
    info_gain    0.5 (log det P_pred - log det P_post) of the onboard EKF's           nats
                 sighting updates (0 without a sighting)
    ===========  ===================================================================  =====================

    ``reward_weights`` defaults: balance 1, coverage 1, sightings 0, wall 0.01, info_gain 0.

    ## Head pan
    ``pan_amplitude * sin(2 pi t / pan_period)`` (rad); ``reset(options={"head_pan": pans})`` uses
    ``pans[t]`` after step t instead (a measured log's pans, to replay it), the sinusoid after the last.
    ``pans`` is a non-empty 1-d array of finite angles (rad, relative to the body); each is wrapped to
    (-pi, pi] (the same camera direction), so the observation and ``info["head_pan"]`` stay in range.

    ## Reset options

    ``options`` is None or a dict whose only valid key is ``"head_pan"`` (None: the sinusoid); any other
    key, a non-dict or a bad value raises a one-line ValueError naming the option.

    ## Starting state

    ``start_pose`` (default (0, 0, 0): field centre facing +x) or ``"random"``: uniform on the field
    with a 500 mm margin, uniform heading, from the episode's seeded RNG.

    ## Episode end

    * terminated: only with ``walls="none"``, when the robot leaves the field;
    * truncated: after ``max_steps`` frames (default 27000 = 15 min).

    The id is registered with ``max_episode_steps=27000`` (the default ``max_steps``), so
    ``gym.make`` adds a ``TimeLimit`` and ``env.spec.max_episode_steps`` is set (``TimeAwareObservation``
    etc. read it). Both limits apply and the earlier ends the episode: the env's own ``max_steps``
    (so the unwrapped env and ``collect`` stand alone) and the wrapper's. For another episode length
    through ``gym.make`` pass ``max_episode_steps=N`` (the spec then says N); a config ``max_steps``
    above it changes nothing there, one below it truncates before the spec's limit.

    ## Arguments

    ``gym.make("aibo_gym:AiboBeacons-v0", config={...}, render_mode=None | "rgb_array" | "human")``;
    the ``aibo_gym:`` prefix imports the package (and so registers the id) in any process, e.g. the
    workers of ``SubprocVecEnv`` or ``gym.make_vec(..., vectorization_mode="async")``; plain
    ``"AiboBeacons-v0"`` works after ``import aibo_gym``. Actions outside ``action_space`` (e.g. 1.5)
    raise ValueError; Python and NumPy integers are accepted.
    see :mod:`aibo_gym.config` for every key (unknown keys or bad values raise ValueError).
    ``"rgb_array"`` returns a top-down uint8 image (0.1 px/mm, or less so that its long side stays
    within :data:`aibo_gym.render.MAX_IMAGE_PX` = 1280 px); ``"human"`` shows it with matplotlib when a
    display exists, else warns once and shows nothing, pausing ``1 / metadata["render_fps"]`` s per frame.
    The instance's ``metadata["render_fps"]`` is ``1 / dt`` (30 by default), the rate video recorders use.
    ``step`` before the first ``reset`` raises ``gymnasium.error.ResetNeeded``.

    ## Seeding

    Everything random uses ``self.np_random`` from ``reset(seed=...)``: each frame draws exactly
    8 normals then 2 uniforms, whatever happens: normals 0-2 the slip (x, y, theta), 3-5 the large
    slip, 6-7 the height and angle noise; uniform 0 decides the large slip, uniform 1 the detection.
    ``start_pose="random"`` draws 3 uniforms at reset before any frame. Effects never draw from it:
    each has its own stream (:mod:`aibo_gym.effects`), so enabling one leaves the rest unchanged.
    The true action model depends only on ``robot_seed``.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 30}

    def __init__(self, config: dict[str, Any] | None = None, render_mode: str | None = None) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode {render_mode!r} (valid choices: None, 'human', 'rgb_array')")
        self.config = make_config(config)
        self.render_mode = render_mode
        cfg = self.config
        self.metadata = {**self.metadata, "render_fps": 1.0 / float(cfg["dt"])}  # frames per simulated second
        self._reset_done = False
        self.n_beacons = len(cfg["beacons"])
        self.velocities = true_velocities(cfg)
        self.velocities.flags.writeable = False  # effects see it through Frame.velocities
        self.attempted = attempted_velocities()
        self.sigma_height, self.sigma_angle = sensor_sigmas(cfg)
        self.camera = Camera(cfg, self.sigma_height, self.sigma_angle)
        self.walls = make_walls(cfg)
        self.effects = EffectChain(cfg)
        self.max_sightings = self.effects.max_sightings
        k = self.max_sightings
        self._no_sightings = (np.full(k, -1, dtype=np.int64), np.zeros(k), np.zeros(k), np.zeros(k, dtype=bool))
        self.dt = float(cfg["dt"])
        self._disp = (self.velocities * self.dt).tolist()  # per-frame displacement per action
        self._attempted = self.attempted.tolist()
        self._slip = list(cfg["slip_std"])
        # a full slip covariance: slip = L z with L its lower Cholesky factor (the same 3 normals)
        self._slip_chol = None if cfg["slip_cov"] is None else np.linalg.cholesky(np.asarray(cfg["slip_cov"])).tolist()
        self._pan_schedule: np.ndarray | None = None
        self._big = list(cfg["big_slip_std"])
        self._beacons = np.asarray(cfg["beacons"], dtype=float)
        self._beacons.flags.writeable = False
        self.action_space = spaces.Discrete(N_ACTIONS)
        b = self.n_beacons
        low = np.concatenate([np.zeros(b), [-HEIGHT_BOUND_PX, -np.pi, 0.0, -np.pi, -1.0, -1.0, -1.0]])
        high = np.concatenate([np.ones(b), [HEIGHT_BOUND_PX, np.pi, 1.0, np.pi, 1.0, 1.0, 1.0]])
        self.observation_space = spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)
        self.pose = (0.0, 0.0, 0.0)
        self.start_pose = [0.0, 0.0, 0.0]
        self.steps = 0
        self.last_sightings: list[Sighting] = []
        self.head_pan = 0.0
        self._episode = -1  # resets since the last seeded one (effects' streams)
        self._command, self._previous_command, self._command_start = NO_COMMAND, NO_COMMAND, 0
        self._renderer = None
        self.tracker = None if cfg["reward"] == "none" else OnboardTracker(cfg)  # the onboard state the rewards use
        self._weights = [(t, float(cfg["reward_weights"][t])) for t in REWARD_TERMS]
        self._zero_terms = dict.fromkeys(REWARD_TERMS, 0.0)

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        opts = check_reset_options(options, {"head_pan": self._check_pan_schedule})
        super().reset(seed=seed)
        self._reset_done = True
        self._episode = 0 if seed is not None else self._episode + 1
        self.effects.reset(max(self.np_random_seed, 0), self._episode)
        x, y, th = draw_start(self.config, self.np_random)
        x, y = self.walls.reset(x, y)
        self.pose = (x, y, wrap_angle(th))
        self.start_pose = list(self.pose)
        self.steps = 0
        self._pan_schedule = opts["head_pan"]
        self.head_pan = self._pan(0)
        self.last_sightings = []
        self._command, self._previous_command, self._command_start = NO_COMMAND, NO_COMMAND, 0
        if self.tracker is not None:
            self.tracker.reset()
        obs = self._observation([], self.head_pan, None)
        info = self._info([], np.zeros(3), False, dict(self._zero_terms))
        if self.render_mode is not None:
            self._get_renderer().reset()
            self._renderer.record(self.pose)
        if self.render_mode == "human":
            self.render()
        return obs, info

    def step(self, action):
        if not self._reset_done:
            raise ResetNeeded("AiboBeacons-v0: call reset() before step()")
        a = self._check_action(action)
        rng = self.np_random
        z = rng.standard_normal(8).tolist()
        u = rng.random(2).tolist()
        cfg = self.config
        pan = self._pan(self.steps + 1)
        frame = self._frame(a, pan)
        x, y, th = self.pose
        dx, dy, dth, wx, wy = self._displacement(a, z, u[0], frame)
        nx, ny, nth = move(x, y, th, dx, dy, dth)
        if wx or wy:
            nx, ny = nx + wx, ny + wy
        cx, cy, left = self.walls.move(x, y, nx, ny, self.dt)
        contact = abs(cx - nx) + abs(cy - ny) > WALL_CONTACT_TOL_MM
        self.pose = (cx, cy, wrap_angle(nth))
        self.steps += 1
        self.head_pan = pan
        sightings = self._sense(u[1], z[6], z[7], frame, contact)
        self.last_sightings = sightings
        obs = self._observation(sightings, pan, a)
        if self.tracker is None:
            reward, terms = 0.0, dict(self._zero_terms)
        else:
            terms = self.tracker.step(a, [(s.beacon, s.height, s.angle) for s in sightings])
            reward = float(sum(w * terms[t] for t, w in self._weights))
        info = self._info(sightings, self.velocities[a].copy(), contact, terms)
        truncated = self.steps >= cfg["max_steps"]
        if self._renderer is not None:
            self._renderer.record(self.pose)
        if self.render_mode == "human":
            self.render()
        return obs, reward, bool(left), bool(truncated), info

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; use render_mode='rgb_array'.")
            return None
        renderer = self._get_renderer()
        if self.render_mode == "rgb_array":
            return renderer.draw()
        renderer.show()
        return None

    def _get_renderer(self):
        if self._renderer is None:
            from ..render import Renderer

            self._renderer = Renderer(self)
        return self._renderer

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    # ------------------------------------------------------------------ internals
    @staticmethod
    def _check_pan_schedule(value: Any) -> np.ndarray:
        """Reset option ``head_pan`` (not None): the head pan (rad, relative to the body) after each step, e.g. a
        measured log's (``Trajectory.head_pan``) to replay it, each wrapped to (-pi, pi]; the config's sinusoid
        after the last. ValueError naming the option unless a non-empty 1-d array of finite numbers."""
        want = "a non-empty 1-d array of finite angles (rad), one per step"
        pans = option_array("head_pan", value, "iuf", want).astype(float)
        if not np.all(np.isfinite(pans)):
            raise ValueError(f"reset option 'head_pan': expected {want}, got non-finite values")
        return np.array([wrap_angle(p) for p in pans.tolist()])

    def _pan(self, step: int) -> float:
        """Head pan (rad) at the end of frame ``step`` (0: at reset): the schedule's or the sinusoid's."""
        sched = self._pan_schedule
        if sched is not None and 1 <= step <= len(sched):
            return float(sched[step - 1])
        return head_pan(step * self.dt, self.config["pan_amplitude"], self.config["pan_period"])

    def _check_action(self, action: Any) -> int:
        """``action`` as an int; ValueError for anything ``action_space.contains`` rejects."""
        if type(action) is int and 0 <= action < N_ACTIONS:  # the common case, without the space's checks
            return action
        if not self.action_space.contains(action):
            raise ValueError(f"action {action!r}: not in the action space Discrete({N_ACTIONS}) (an integer 0..{N_ACTIONS - 1})")
        return int(action)

    def _frame(self, a: int, pan: float) -> Frame | None:
        """Track the command; the frame context for the effects (None without effects)."""
        if a != self._command:
            self._previous_command, self._command, self._command_start = self._command, a, self.steps
        if not self.effects.effects:
            return None
        field = self.config["field"]
        return Frame(
            index=self.steps, time=self.steps * self.dt, dt=self.dt, command=a,
            previous_command=self._previous_command, command_start=self._command_start,
            pose_before=self.pose, pose_after=None, head_pan=pan, wall_contact=False,
            field=(field[0], field[1]), beacons=self._beacons, velocities=self.velocities,
        )

    def _displacement(self, a: int, z: list[float], u_big: float, frame: Frame | None):
        """Robot-frame displacement (mm, mm, rad) and world-frame offset (mm, mm) of one frame."""
        vx, vy, vth = self._disp[a]
        if self._slip_chol is None:
            s = self._slip
            dx, dy, dth = vx + s[0] * z[0], vy + s[1] * z[1], vth + s[2] * z[2]
        else:
            (l00, _, _), (l10, l11, _), (l20, l21, l22) = self._slip_chol
            dx, dy, dth = vx + l00 * z[0], vy + l10 * z[0] + l11 * z[1], vth + l20 * z[0] + l21 * z[1] + l22 * z[2]
        if u_big < self.config["big_slip_prob"]:
            b = self._big
            dx, dy, dth = dx + b[0] * z[3], dy + b[1] * z[4], dth + b[2] * z[5]
        if frame is None or not self.effects.motion_effects:
            return dx, dy, dth, 0.0, 0.0
        m = self.effects.move(Motion(np.array([dx, dy, dth]), self.velocities[a].copy()), frame)
        return float(m.disp[0]), float(m.disp[1]), float(m.disp[2]), float(m.world[0]), float(m.world[1])

    def _sense(self, u: float, zh: float, za: float, frame: Frame | None, contact: bool) -> list[Sighting]:
        """The sightings of the frame's end pose: the camera's, then the sensing effects."""
        x, y, th = self.pose
        s = self.camera.sight(x, y, th, self.head_pan, u, zh, za)
        sightings = [] if s is None else [s]
        if frame is None:
            return sightings
        frame.pose_after, frame.wall_contact = self.pose, contact
        sightings = self.effects.sense(sightings, frame)
        for s in sightings:
            s.angle = wrap_angle(float(s.angle))
        return sightings

    def _observation(self, sightings: list[Sighting], pan: float, action: int | None) -> np.ndarray:
        b = self.n_beacons
        obs = np.zeros(b + 7, dtype=np.float32)
        if sightings:
            s = sightings[0]
            obs[s.beacon] = 1.0
            obs[b] = min(max(s.height, -HEIGHT_BOUND_PX), HEIGHT_BOUND_PX)
            obs[b + 1] = s.angle
            obs[b + 2] = 1.0
        obs[b + 3] = pan
        if action is not None:
            obs[b + 4 : b + 7] = self._attempted[action]
        return obs

    def _info(self, sightings: list[Sighting], velocity: np.ndarray, contact: bool, rewards: dict[str, float]) -> dict[str, Any]:
        return {
            "rewards": rewards,
            "pose": np.array(self.pose),
            "head_pan": self.head_pan,
            "action_velocity": velocity,
            "wall_contact": bool(contact),
            "sightings": self._sightings_info(sightings),
        }

    def _sightings_info(self, sightings: list[Sighting]) -> dict[str, Any]:
        """``info["sightings"]``: fixed-shape arrays of ``max_sightings`` rows and a count."""
        beacon, height, angle, spurious = (a.copy() for a in self._no_sightings)
        for j, s in enumerate(sightings):
            beacon[j], height[j], angle[j], spurious[j] = s.beacon, s.height, s.angle, s.spurious
        return {"count": len(sightings), "beacon": beacon, "height": height, "angle": angle, "spurious": spurious}
