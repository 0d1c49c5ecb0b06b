"""Simulator effects OUTSIDE the catalogue (no learner twin): what the discrepancy search's "none of the above"
check (``learners.model.probes``) is measured on. Not registered at import, so the catalogue's registries stay
as they are: ``registered(cls)`` makes one available to an env config for a while."""

from __future__ import annotations

import math
from contextlib import contextmanager
from typing import Iterator

import numpy as np

from aibo_gym.context import Frame, Motion
from aibo_gym.effects import EFFECTS, Effect


class SlopedFloor(Effect):
    """Walking speed x (1 + ``grade`` cos(heading - ``downhill_rad``)): faster downhill, slower uphill; the turn is
    unchanged. No catalogue effect is this: ``floor_drift`` adds a constant world-frame velocity whatever the
    command, ``velocity_fade`` shrinks the speed with time."""

    name = "sloped_floor"
    defaults = {"grade": 0.0, "downhill_rad": 0.0}
    bounds = {"grade": (0.0, 0.9)}

    def motion(self, m: Motion, frame: Frame) -> Motion:
        factor = 1.0 + self.params["grade"] * math.cos(frame.pose_before[2] - self.params["downhill_rad"])
        m.set_velocity(m.velocity * np.array([factor, factor, 1.0]), frame.dt)
        return m


@contextmanager
def registered(cls: type[Effect]) -> Iterator[type[Effect]]:
    """``cls`` usable by name in an env config inside the ``with`` block (removed after)."""
    EFFECTS[cls.name] = cls
    try:
        yield cls
    finally:
        EFFECTS.pop(cls.name, None)
