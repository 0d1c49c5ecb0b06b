"""Simulated logs shared by the learner and CLI tests (built once per test session)."""

from __future__ import annotations

from functools import lru_cache

from aibo_gym.collect import collect


@lru_cache(maxsize=None)
def sim_log(steps: int = 6000, seed: int = 3, noise: str = "paper-sim", robot_seed: int = 0):
    """A random-balanced log with ground truth (returns the same object per arguments: do not mutate)."""
    return collect({"noise": noise, "robot_seed": robot_seed}, steps=steps, seed=seed)
