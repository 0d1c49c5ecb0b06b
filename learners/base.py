"""The learner plugin interface and registry.

A learner turns a list of logs (aibo-trajectory/2) into a learned ``learners.model.Model``:

    learner = get_learner("em")(**options)
    result = learner.fit(logs, init=None, progress=callback)

Third-party packages add learners through the entry-point group ``aibo.learners``
(``name = "package.module:LearnerClass"``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import Any, Callable, Protocol

from aibo_core.trajectory import Trajectory
from learners.model.model import Model

ENTRY_POINT_GROUP = "aibo.learners"


@dataclass
class IterationRecord:
    """One EM iteration (or one step of another learner): for progress and learning curves."""

    iteration: int
    loglik: float
    seconds: float
    params: Model


@dataclass
class LearnResult:
    """What every learner returns."""

    learner: str
    params: Model
    iterations: int
    converged: bool
    loglik: list[float] = field(default_factory=list)
    pruned_observations: int = 0
    history: list[IterationRecord] = field(default_factory=list)
    #: run information: a dict, or a typed record read the same way by key (``learners.em.info.FitInfo``)
    info: Any = field(default_factory=dict)


ProgressFn = Callable[[IterationRecord], None]


class Learner(Protocol):
    name: str

    def fit(self, logs: list[Trajectory], init: Model | None = None, progress: ProgressFn | None = None) -> LearnResult:
        ...


def _builtin() -> dict[str, str]:
    return {"em": "learners.em.learner:EMLearner", "oracle": "learners.oracle:OracleLearner"}


def available() -> dict[str, str]:
    """Learner names and their ``module:Class`` targets (built-ins plus installed plugins)."""
    found = dict(_builtin())
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        found.setdefault(ep.name, ep.value)
    return found


def get_learner(name: str):
    """The learner class registered under ``name``; ValueError naming the valid choices otherwise."""
    targets = available()
    if name not in targets:
        raise ValueError(f"unknown learner '{name}' (choose from: {', '.join(sorted(targets))})")
    module_name, _, attr = targets[name].partition(":")
    module = __import__(module_name, fromlist=[attr])
    return getattr(module, attr)
