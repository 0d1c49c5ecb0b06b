"""Scores of a model on data: the held-out predictive log-likelihood (the gap) and the consistency of
the innovations (normalized innovation squared against its chi-square band, and whiteness)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from aibo_core.trajectory import Trajectory
from learners.arrays.batch import make_batch
from learners.em.estep import e_step
from learners.em.options import DEFAULT_GATE
from learners.em.predictive import predictive_logdens, sightings_logdens
from learners.model.model import Model

from .split import heldout_mask

GAP_METRIC = "heldout_nll_per_sighting"
__all__ = ["GAP_METRIC", "Score", "predictive_logdens", "score"]


@dataclass
class Score:
    """How well a model predicts the logs."""

    heldout_loglik: float  # log p(held-out sightings | training sightings), nats
    n_heldout: int
    gap: float  # GAP_METRIC: -heldout_loglik / n_heldout (nats per sighting; lower is better)
    nis_mean: float  # mean normalized innovation squared (2 expected: 2-d sightings)
    nis_outside: float  # share outside the chi-square(2) 95% band (0.05 expected)
    whiteness: float  # lag-1 autocorrelation of the normalized size innovations (0 expected)
    nis: np.ndarray  # (S,) per sighting, NaN where gated

    def as_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in self.__dict__.items() if k != "nis"}


def score(model: Model, logs: list[Trajectory], gate: float | None = None) -> Score:
    """The held-out one-step predictive log-likelihood: the sum, over the held-out sightings, of the
    log density the forward filter (run over all sightings, the model fitted on the training half)
    predicted for each. ``gate``: leave out sightings whose Mahalanobis^2 exceeds it (default none:
    the caller removed outliers once for all models)."""
    batch = make_batch(logs)
    held = np.concatenate([heldout_mask(tr) for tr in logs])
    post_all = e_step(model, batch, "compiled", gate)
    nis = np.array(post_all.mahal2, copy=True)
    idx = np.flatnonzero(held & batch.used & ~(nis > (gate if gate is not None else np.inf)))
    heldout = float(np.sum(sightings_logdens(model, batch, post_all, idx)))
    n = len(idx)
    ok = np.isfinite(nis) & (nis <= DEFAULT_GATE)
    lo, hi = stats.chi2.ppf([0.025, 0.975], 2)
    z = nis[ok]
    seq = np.sqrt(z) - np.mean(np.sqrt(z))
    white = float(np.sum(seq[1:] * seq[:-1]) / np.sum(seq * seq)) if len(seq) > 2 else 0.0
    return Score(heldout, n, -heldout / max(n, 1), float(np.mean(z)),
                 float(np.mean((z < lo) | (z > hi))), white, nis)
