"""A candidate of the discrepancy search: one effect (or probe) fitted in one round, and the verdicts of the checks it
went through (``learners.discrepancy.checks``). Whether it is significant, identifiable, and what the report says of
it are read off its verdicts, never set by hand."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from learners.model.model import Model


@dataclass
class Verdict:
    """What one check said of one candidate.

    ``decides``: whether ``passed`` counts towards the candidate's significance (an annotating check only informs);
    ``identifiable``: False when the check found that the data cannot tell the effect from the base model;
    ``gains``: the check's likelihood gains in nats (``train``, ``heldout``); ``p``: its test's p-value (None without
    a test); ``overstatement``: the factor by which the Fisher information overstated the data's information about the
    effect's parameters, where the check measured it (``checks.RobustLikelihoodRatio``), and ``standard_errors``: their
    robust standard errors on the training halves there (by parameter, the model file's units); ``escape``: a base model
    without the effect that the check fitted, with its training log-likelihood (the search may continue from it; not
    reported)."""

    name: str
    passed: bool
    decides: bool = True
    gains: dict[str, float] = field(default_factory=dict)
    p: float | None = None
    note: str = ""
    identifiable: bool = True
    overstatement: float | None = None
    standard_errors: dict[str, Any] | None = None
    escape: tuple[Model, float] | None = field(default=None, repr=False)

    def as_dict(self) -> dict[str, Any]:
        out = {"name": self.name, "passed": self.passed, "decides": self.decides, "gains": dict(self.gains),
               "p": self.p, "note": self.note}
        return (out | ({"overstatement": self.overstatement} if self.overstatement is not None else {})
                | ({"standard_errors": self.standard_errors} if self.standard_errors is not None else {}))


@dataclass
class Candidate:
    """One effect tried in one round: its fit and the verdicts of its checks, in the order they ran.

    ``gain_train``, ``gain_heldout`` (nats over the round's null), ``dof`` and ``p_value`` are the likelihood-ratio
    test's (``checks.LikelihoodRatio``)."""

    name: str
    parameters: dict[str, Any]
    gain_train: float  # nats, training log-likelihood over the null
    gain_heldout: float  # nats, held-out log-likelihood over the null
    dof: int
    p_value: float
    checks: list[Verdict] = field(default_factory=list)
    seconds: float = 0.0
    model: Model | None = field(default=None, repr=False)
    loglik: float = field(default=float("nan"), repr=False)  # ``model``'s training log-likelihood (nats)
    start: Model | None = field(default=None, repr=False)  # the model its fit started from
    #: a grid parameter's profile: name -> [grid values walked, training log-likelihoods (nats)]
    profile: dict[str, list[list[float]]] = field(default_factory=dict)
    #: the null's (training, held-out) log-likelihoods when its own fit holds one (a grid's neutral point), else None:
    #: the round's
    null: tuple[float, float] | None = field(default=None, repr=False)

    @property
    def significant(self) -> bool:
        """Every deciding check passed (and at least one ran)."""
        deciding = [v for v in self.checks if v.decides]
        return bool(deciding) and all(v.passed for v in deciding)

    @property
    def identifiable(self) -> bool:
        return all(v.identifiable for v in self.checks)

    @property
    def note(self) -> str:
        """The last check's word on it (the one that decided, or the last annotation)."""
        return next((v.note for v in reversed(self.checks) if v.note), "")

    @property
    def standard_errors(self) -> dict[str, Any]:
        """Its parameters' robust standard errors in its fit on the training halves, where a check measured them
        (``Verdict.standard_errors``; {} where none did: a grid parameter, a candidate not tested that far)."""
        return next((v.standard_errors for v in self.checks if v.standard_errors), {})

    @property
    def escape(self) -> Model | None:
        """The last base model without the effect that a check fitted (None: none)."""
        return self._last_escape()[0]

    @property
    def escape_ll(self) -> float:
        """:attr:`escape`'s training log-likelihood (nats; -inf without one)."""
        return self._last_escape()[1]

    def _last_escape(self) -> tuple[Model | None, float]:
        return next((v.escape for v in reversed(self.checks) if v.escape is not None), (None, -math.inf))

    def verdict(self, name: str) -> Verdict | None:
        return next((v for v in self.checks if v.name == name), None)

    def as_dict(self) -> dict[str, Any]:
        """The report's row: the test's numbers, the flags read off the verdicts and the whole trail (``checks``)."""
        return {"name": self.name, "parameters": {k: np.asarray(v).tolist() for k, v in self.parameters.items()},
                "gain_train": self.gain_train, "gain_heldout": self.gain_heldout, "dof": self.dof,
                "p_value": self.p_value, "significant": self.significant, "identifiable": self.identifiable,
                "note": self.note, "seconds": self.seconds, "profile": self.profile,
                "checks": [v.as_dict() for v in self.checks]}
