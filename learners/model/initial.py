"""The initial state pi: a Gaussian over each log's first pose."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from learners.model.parameters import Component, Param


@dataclass(frozen=True)
class InitialState(Component):
    """pi = N(mean, cov) over the first pose (x mm, y mm, theta rad) of one log."""

    mean: np.ndarray  # (3,)
    cov: np.ndarray  # (3, 3)

    PARAMS: ClassVar[dict[str, Param]] = {
        "mean": Param("mm, mm, rad", "scaled", (100.0, 100.0, 0.1)),
        "cov": Param("mm^2, mm^2, rad^2", "logchol", order=1),
    }


#: Default start pose belief: the simulator's start (field centre, facing +x), 100 mm / 0.1 rad std.
DEFAULT_INITIAL = InitialState(np.zeros(3), np.diag([100.0**2, 100.0**2, 0.1**2]))
