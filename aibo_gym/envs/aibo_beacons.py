"""``AiboBeacons-v0``: a simulated Sony Aibo walking on a 5.4 m x 3.6 m field with four beacons."""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from aibo_core.actions import N_ACTIONS, attempted_velocities
from ..camera import Camera, head_pan
from ..config import START_MARGIN_MM, make_config, sensor_sigmas
from ..effects import build_effects
from ..robot import move, true_velocities, wrap_angle
from ..walls import make_walls

HEIGHT_BOUND_PX = 1000.0  # observation bound for the beacon height; raw values are in info


class AiboBeaconsEnv(gym.Env):
    """A legged robot with a scanning camera, walking among known beacons (Stronger & Stone, IV).

    The robot executes one of 40 walk actions per frame (``dt`` = 1/30 s) and, with its head
    panning side to side, sees at most one beacon per frame. Its true action model (the actual
    velocity of each action) is hidden; learning it, and the sensor model, from a log is the task.

    ## Action space

    ``Discrete(40)``: action ``8*i + j`` walks "as fast as possible" with normalized turn
    ``A_TURN[i]`` in {-1/2, -1/6, 0, 1/6, 1/2} and direction ``B_DIRECTION[j]`` in
    {0, pi/4, ..., -pi/4} (see :mod:`aibo_gym.actions`). Its *true* velocity
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
    sighting.

    ## Info

    ``pose``: true pose after the step, ndarray (x mm, y mm, theta rad in (-pi, pi]);
    ``sighting``: None or ``{"beacon": int, "height": px, "angle": rad}`` (unclipped float64);
    ``head_pan``: rad; ``action_velocity``: ndarray, the true velocity of the action executed
    (mm/s, mm/s, rad/s; zeros after reset).

    ## Motion

    Robot-frame displacement per frame = v dt + N(0, diag(slip_std^2)) (+ a large slip
    N(0, diag(big_slip_std^2)) with probability ``big_slip_prob``), then motion effects;
    new pose = pose + R(theta) disp, then the wall model (``walls``).

    ## Rewards

    Always 0 (``reward="none"``, the only choice today); an exploration reward comes with a later
    SB3 issue.

    ## Starting state

    ``start_pose`` (default (0, 0, 0): field centre facing +x) or ``"random"``: uniform on the field
    with a 500 mm margin, uniform heading, from the episode's seeded RNG.

    ## Episode end

    * terminated: only with ``walls="none"``, when the robot leaves the field;
    * truncated: after ``max_steps`` frames (default 27000 = 15 min).

    ## Arguments

    ``gym.make("AiboBeacons-v0", config={...}, render_mode=None | "rgb_array" | "human")``;
    see :mod:`aibo_gym.config` for every key (unknown keys or bad values raise ValueError).
    ``"rgb_array"`` returns a top-down uint8 image; ``"human"`` shows it with matplotlib when a
    display exists, else warns once and shows nothing.

    ## Seeding

    Everything random uses ``self.np_random`` from ``reset(seed=...)``: each frame draws exactly
    8 normals and 2 uniforms, whatever happens. The true action model depends only on ``robot_seed``.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 30}

    def __init__(self, config: dict[str, Any] | None = None, render_mode: str | None = None) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode {render_mode!r} (valid choices: None, 'human', 'rgb_array')")
        self.config = make_config(config)
        self.render_mode = render_mode
        cfg = self.config
        self.n_beacons = len(cfg["beacons"])
        self.velocities = true_velocities(cfg)
        self.attempted = attempted_velocities()
        self.sigma_height, self.sigma_angle = sensor_sigmas(cfg)
        self.camera = Camera(cfg, self.sigma_height, self.sigma_angle)
        self.walls = make_walls(cfg)
        self.motion_effects, self.sense_effects = build_effects(cfg["effects"])
        self.dt = float(cfg["dt"])
        self._disp = (self.velocities * self.dt).tolist()  # per-frame displacement per action
        self._attempted = self.attempted.tolist()
        self._slip = list(cfg["slip_std"])
        self._big = list(cfg["big_slip_std"])
        self.action_space = spaces.Discrete(N_ACTIONS)
        b = self.n_beacons
        low = np.concatenate([np.zeros(b), [-HEIGHT_BOUND_PX, -np.pi, 0.0, -np.pi, -1.0, -1.0, -1.0]])
        high = np.concatenate([np.ones(b), [HEIGHT_BOUND_PX, np.pi, 1.0, np.pi, 1.0, 1.0, 1.0]])
        self.observation_space = spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)
        self.pose = (0.0, 0.0, 0.0)
        self.start_pose = [0.0, 0.0, 0.0]
        self.steps = 0
        self.last_sighting: dict[str, Any] | None = None
        self.head_pan = 0.0
        self._renderer = None

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        x, y, th = self._draw_start()
        x, y = self.walls.reset(x, y)
        self.pose = (x, y, wrap_angle(th))
        self.start_pose = list(self.pose)
        self.steps = 0
        self.head_pan = head_pan(0.0, self.config["pan_amplitude"], self.config["pan_period"])
        self.last_sighting = None
        obs = self._observation(None, self.head_pan, None)
        info = self._info(None, np.zeros(3))
        if self.render_mode is not None:
            self._get_renderer().reset()
            self._renderer.record(self.pose)
        if self.render_mode == "human":
            self.render()
        return obs, info

    def step(self, action):
        a = int(action)
        if not 0 <= a < N_ACTIONS:
            raise ValueError(f"action {action!r} outside 0..{N_ACTIONS - 1}")
        rng = self.np_random
        z = rng.standard_normal(8).tolist()
        u = rng.random(2).tolist()
        x, y, th = self.pose
        dx, dy, dth = self._displacement(a, z, u[0])
        nx, ny, nth = move(x, y, th, dx, dy, dth)
        nx, ny, left = self.walls.move(x, y, nx, ny, self.dt)
        nth = wrap_angle(nth)
        self.pose = (nx, ny, nth)
        self.steps += 1
        cfg = self.config
        pan = head_pan(self.steps * self.dt, cfg["pan_amplitude"], cfg["pan_period"])
        self.head_pan = pan
        sighting = self._sense(nx, ny, nth, pan, u[1], z[6], z[7])
        self.last_sighting = sighting
        obs = self._observation(sighting, pan, a)
        info = self._info(sighting, self.velocities[a].copy())
        truncated = self.steps >= cfg["max_steps"]
        if self._renderer is not None:
            self._renderer.record(self.pose)
        if self.render_mode == "human":
            self.render()
        return obs, 0.0, bool(left), bool(truncated), info

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
    def _draw_start(self) -> tuple[float, float, float]:
        sp = self.config["start_pose"]
        if sp != "random":
            return float(sp[0]), float(sp[1]), float(sp[2])
        hl = 0.5 * self.config["field"][0] - START_MARGIN_MM
        hw = 0.5 * self.config["field"][1] - START_MARGIN_MM
        r = self.np_random.uniform([-hl, -hw, -math.pi], [hl, hw, math.pi])
        return float(r[0]), float(r[1]), float(r[2])

    def _displacement(self, a: int, z: list[float], u_big: float) -> tuple[float, float, float]:
        """Robot-frame displacement of one frame (mm, mm, rad), noise and motion effects included."""
        vx, vy, vth = self._disp[a]
        s = self._slip
        dx, dy, dth = vx + s[0] * z[0], vy + s[1] * z[1], vth + s[2] * z[2]
        if u_big < self.config["big_slip_prob"]:
            b = self._big
            dx, dy, dth = dx + b[0] * z[3], dy + b[1] * z[4], dth + b[2] * z[5]
        if self.motion_effects:
            disp = np.array([dx, dy, dth])
            pose = np.array(self.pose)
            for effect in self.motion_effects:
                disp = effect.motion(disp, a, pose, self.np_random)
            dx, dy, dth = (float(v) for v in disp)
        return dx, dy, dth

    def _sense(self, x: float, y: float, th: float, pan: float, u: float, zh: float, za: float):
        s = self.camera.sight(x, y, th, pan, u, zh, za)
        if s is None:
            return None
        i, height, angle, d = s
        for effect in self.sense_effects:
            height, angle = effect.sense(height, angle, d, self.np_random)
            angle = wrap_angle(float(angle))
        return {"beacon": i, "height": float(height), "angle": float(angle)}

    def _observation(self, sighting: dict[str, Any] | None, pan: float, action: int | None) -> np.ndarray:
        b = self.n_beacons
        obs = np.zeros(b + 7, dtype=np.float32)
        if sighting is not None:
            obs[sighting["beacon"]] = 1.0
            obs[b] = min(max(sighting["height"], -HEIGHT_BOUND_PX), HEIGHT_BOUND_PX)
            obs[b + 1] = sighting["angle"]
            obs[b + 2] = 1.0
        obs[b + 3] = pan
        if action is not None:
            obs[b + 4 : b + 7] = self._attempted[action]
        return obs

    def _info(self, sighting: dict[str, Any] | None, velocity: np.ndarray) -> dict[str, Any]:
        return {
            "pose": np.array(self.pose),
            "sighting": sighting,
            "head_pan": self.head_pan,
            "action_velocity": velocity,
        }
