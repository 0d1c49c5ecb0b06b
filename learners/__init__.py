"""Learners that read logs (``aibo_core.trajectory``), never environments.

Public API: ``load_model(path)`` returns the ``Model`` of a model file; ``model.action.velocity(commands)``
gives (N, 3) velocities [forward mm/s, lateral mm/s, turn rad/s] for discrete command indices (N,) or
continuous commands (N, k); ``model.sensor.mean(distances_mm)`` the mean size measurement (px or mm)
and ``model.sensor.std(distances_mm)`` the (N, 2) standard deviations [size, bearing rad].
"""

from __future__ import annotations

from typing import Any

__all__ = ["load_model", "Model"]


def __getattr__(name: str) -> Any:
    """``load_model`` and ``Model`` imported on first use: importing any ``learners`` module (e.g. the light
    ``learners.em.options`` the command line reads) does not load the model's SciPy dependencies."""
    if name == "load_model":
        from learners.model.io import load_model

        return load_model
    if name == "Model":
        from learners.model.model import Model

        return Model
    raise AttributeError(f"module 'learners' has no attribute {name!r}")
