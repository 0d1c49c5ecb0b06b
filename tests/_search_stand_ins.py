"""Stand-ins for the discrepancy search's models and context, for testing its rules without a fit: an effect with
the flags a test sets, a model that is its effects, and a context whose refit returns its start and whose
likelihoods the test assigns per set of effect names."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from learners.discrepancy.fitting import lr_test


@dataclass(frozen=True)
class StandInEffect:
    name: str
    k: int = 1  # dof
    why_negligible: str = ""
    why_implausible: str = ""

    def dof(self) -> int:
        return self.k

    def negligible(self, n_sightings: int) -> str:
        return self.why_negligible

    def implausible(self) -> str:
        return self.why_implausible


@dataclass(frozen=True)
class StandInModel:
    effects: tuple[StandInEffect, ...]

    def effect(self, name):
        return next((e for e in self.effects if e.name == name), None)

    def without_effect(self, name):
        return StandInModel(tuple(e for e in self.effects if e.name != name))


@dataclass
class StandInContext:
    """A stand-in ``SearchContext``: ``train_ll`` / ``heldout_ll`` map a frozenset of effect names to the training and
    held-out log-likelihoods (nats) the test assigns; one test in the round."""

    train_ll: dict
    heldout_ll: dict = field(default_factory=dict)
    logs: tuple = ()
    n_tests: int = 1
    factor: float = 1.0  # what ``overstatement`` returns: the Fisher information's overstatement of the data's
    current: Any = None  # the round's current model
    null_ll: float = math.nan

    def fit(self, init, opts=None):
        return init

    def loglik(self, model):
        return self.train_ll[frozenset(e.name for e in model.effects)]

    def heldout(self, model):
        return self.heldout_ll[frozenset(e.name for e in model.effects)]

    def overstatement(self, model, name):
        return self.factor, {}

    def test(self, gain, held_gain, dof):
        return lr_test(gain, held_gain, dof, self.n_tests)
