"""The hold-level explorer env: one agent step = one command held for ``hold_s`` seconds.

:class:`HoldWrapper` wraps ``AiboBeacons-v0`` (built with ``reward="explore"``): its action is the
command (``Discrete(40)``), which it executes for ``hold_s`` (default 5 s = 150 frames, fewer if
the episode ends), summing the per-frame exploration rewards (the env's named terms, weighted by
``reward_weights``; the summed terms are in ``info["rewards"]``). Its observation is the onboard
tracker's :meth:`~aibo_gym.policies.onboard.OnboardTracker.features` (onboard only: the EKF
estimate, command use, sightings per command, time), the same vector the ``sb3`` policy builds
when collecting. With ``shield`` (default) a command whose predicted path would leave the field
(``margin_mm``) is replaced by the safe command of most similar attempted velocity, the same rule
at training and at collection time (``info["command"]`` is the command executed).

For SB3's subprocess vector envs use ``make_explorer_vec_env`` (the ``"aibo_gym:AiboBeacons-v0"``
id, so workers import the package; ``OMP_NUM_THREADS=1`` for the workers unless set).
"""

from __future__ import annotations

import os
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from aibo_core.actions import N_ACTIONS, attempted_velocities

from .config import REWARD_TERMS
from .policies.onboard import N_FEATURES

PATH_POINTS = 25
_ATT = attempted_velocities()


def shield_command(tracker, action: int, hold_s: float, margin_mm: float) -> int:
    """``action`` if its predicted hold keeps ``margin_mm`` inside the field; else the safe command
    whose attempted velocity is most similar (largest dot product), or the least bad if none is safe."""
    xy, _ = tracker.predict_holds(hold_s, PATH_POINTS)
    viol = tracker.violation(xy, margin_mm)
    if viol[action] <= 0.0:
        return int(action)
    safe = np.flatnonzero(viol <= 0.0)
    if len(safe) == 0:
        return int(np.argmin(viol))
    return int(safe[np.argmax(_ATT[safe] @ _ATT[action])])


class HoldWrapper(gym.Wrapper):
    """See the module docstring."""

    def __init__(self, env: gym.Env, hold_s: float = 5.0, shield: bool = True, margin_mm: float = 300.0) -> None:
        super().__init__(env)
        base = env.unwrapped
        if getattr(base, "tracker", None) is None:
            raise ValueError("HoldWrapper needs the env built with config reward='explore' (its onboard tracker)")
        if not hold_s > 0:
            raise ValueError(f"hold_s must be positive seconds, got {hold_s!r}")
        self.hold_s = float(hold_s)
        self.hold_frames = max(1, int(round(self.hold_s / base.dt)))
        self.shield, self.margin = bool(shield), float(margin_mm)
        self.action_space = spaces.Discrete(N_ACTIONS)
        self.observation_space = spaces.Box(-5.0, 5.0, shape=(N_FEATURES,), dtype=np.float32)
        self.episode_steps = int(base.config["max_steps"])

    def _features(self) -> np.ndarray:
        return self.env.unwrapped.tracker.features(self.episode_steps)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        _, info = self.env.reset(seed=seed, options=options)
        return self._features(), info

    def step(self, action):
        a = int(action)
        if not 0 <= a < N_ACTIONS:
            raise ValueError(f"action {action!r}: not a command 0..{N_ACTIONS - 1}")
        tracker = self.env.unwrapped.tracker
        if self.shield:
            a = shield_command(tracker, a, self.hold_s, self.margin)
        total, terms = 0.0, dict.fromkeys(REWARD_TERMS, 0.0)
        terminated = truncated = False
        info: dict[str, Any] = {}
        for _ in range(self.hold_frames):
            _, r, terminated, truncated, info = self.env.step(a)
            total += r
            for k, v in info["rewards"].items():
                terms[k] += v
            if terminated or truncated:
                break
        info = {**info, "rewards": terms, "command": a}
        return self._features(), float(total), terminated, truncated, info


def make_explorer_vec_env(config: dict[str, Any], n_envs: int, seed: int, hold_s: float = 5.0,
                          shield: bool = True, subprocess: bool = True):
    """An SB3 vector env of ``n_envs`` hold-level explorers (SB3 imported here)."""
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(k, "1")  # subprocess workers inherit it: one thread each on few cores
    cfg = {**config, "reward": "explore"} if config.get("reward", "none") == "none" else dict(config)
    return make_vec_env(
        "aibo_gym:AiboBeacons-v0", n_envs=n_envs, seed=seed, env_kwargs={"config": cfg},
        wrapper_class=HoldWrapper, wrapper_kwargs={"hold_s": hold_s, "shield": shield},
        vec_env_cls=SubprocVecEnv if subprocess and n_envs > 1 else DummyVecEnv,
    )


#: Robot seeds the information explorer trains on: never robot 0 (where policies were tuned) nor the
#: 100 + s of ``aibo experiment policies`` (its evaluation robots).
TRAIN_ROBOT_SEEDS = (10_000, 1_000_000)


class InfoExplorerEnv(gym.Env):
    """The ``explorer`` policy's training env: one agent step = one command held ``hold_s`` s.

    Its observation is :meth:`~aibo_gym.policies.explorer.ExplorerPolicy.observation` (the running
    onboard information and ``greedy``'s predicted gains), its reward ``reward_scale`` x the increase
    over the hold of :meth:`~aibo_gym.policies.greedy.GreedyPolicy.logdet` (nats: the onboard
    information about the velocity table and the sensor curve). Each reset draws a new robot
    (``robot_seed`` uniform in ``robot_seeds``, from the env's seeded RNG) and a new env seed; an
    episode lasts ``episode_minutes``. The chosen command goes through the same shield as at
    collection (``info["command"]`` is the one executed)."""

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self, config: dict[str, Any] | None = None, hold_s: float = 5.0, episode_minutes: float = 15.0,
                 reward_scale: float = 0.1, robot_seeds: tuple[int, int] = TRAIN_ROBOT_SEEDS) -> None:
        from .config import make_config
        from .policies.explorer import N_INFO_FEATURES, DrivenExplorer

        if not episode_minutes > 0:
            raise ValueError(f"episode_minutes must be positive, got {episode_minutes!r}")
        self.config = dict(config or {}, reward="none")
        base = make_config(self.config)
        self.frames = max(1, int(round(episode_minutes * 60.0 / base["dt"])))
        self.policy = DrivenExplorer(base, seed=0, hold_s=hold_s)
        self.reward_scale, self.robot_seeds = float(reward_scale), tuple(int(s) for s in robot_seeds)
        self.action_space = spaces.Discrete(N_ACTIONS)
        self.observation_space = spaces.Box(-5.0, 5.0, shape=(N_INFO_FEATURES,), dtype=np.float32)
        self.env = None
        self._last: tuple[np.ndarray, dict[str, Any]] | None = None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        from .envs.aibo_beacons import AiboBeaconsEnv

        super().reset(seed=seed)
        robot = int(self.np_random.integers(*self.robot_seeds))
        self.env = AiboBeaconsEnv({**self.config, "robot_seed": robot, "max_steps": self.frames})
        obs, info = self.env.reset(seed=int(self.np_random.integers(2**31)))
        self.policy.rng = np.random.default_rng(int(self.np_random.integers(2**31)))
        self.policy.reset(info)
        return self.policy.observation(), {"robot_seed": robot}

    def step(self, action):
        a = int(action)
        if not 0 <= a < N_ACTIONS:
            raise ValueError(f"action {action!r}: not a command 0..{N_ACTIONS - 1}")
        pol = self.policy
        before = pol.logdet()
        pol.pending = a
        executed = pol.begin_hold()
        terminated = truncated = False
        for _ in range(pol.hold_frames):
            obs, _, terminated, truncated, info = self.env.step(executed)
            pol.observe(obs, info)
            if terminated or truncated:
                break
        pol._close_hold()
        gain = pol.logdet() - before
        return pol.observation(), self.reward_scale * gain, terminated, truncated, {"command": executed, "logdet_gain": gain}
