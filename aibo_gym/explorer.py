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
