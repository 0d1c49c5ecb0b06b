"""Learners that read logs (``aibo_core.trajectory``), never environments.

Public API: ``load_model(path)`` returns the ``Model`` of a model file; ``model.action.velocity(commands)``
gives (N, 3) velocities [forward mm/s, lateral mm/s, turn rad/s] for discrete command indices (N,) or
continuous commands (N, k); ``model.sensor.mean(distances_mm)`` the mean size measurement (px or mm)
and ``model.sensor.std(distances_mm)`` the (N, 2) standard deviations [size, bearing rad].
"""

from learners.model.io import load_model
from learners.model.model import Model

__all__ = ["load_model", "Model"]
