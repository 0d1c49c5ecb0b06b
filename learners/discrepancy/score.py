"""Scores of a model on data: the held-out predictive log-likelihood (the gap) and the consistency of
the innovations (normalized innovation squared against its chi-square band, and whiteness)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from aibo_core import geometry
from aibo_core.trajectory import Trajectory
from learners.em.fit import DEFAULT_GATE, e_step
from learners.inference.batch import Batch, make_batch
from learners.inference.lowered import Lowered
from learners.inference.posterior import Posterior
from learners.inference.reference import AIBO_ANGLE_MASK, ekf_innovation, ekf_update, sighting_model
from learners.model.model import Model

from .split import heldout_mask

GAP_METRIC = "heldout_nll_per_sighting"


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


def predictive_logdens(lo: Lowered, batch: Batch, post: Posterior, idx: np.ndarray) -> np.ndarray:
    """log N(z_j; h(m-), H P- H^T + R) of sightings ``idx``: the one-step predictive density the forward
    filter gave each, from the filtered belief at the start of its frame (mu_alpha, cov_alpha), the
    motion of the frame, and the frame's earlier sightings applied in order (as the E-step does)."""
    out = np.empty(len(idx))
    frame = batch.sight_frame[idx]
    first = batch.sight_start[frame]
    p = batch.frame_to_pose[frame]
    g, F, R3 = geometry.motion(post.mu_alpha[p], lo.disp[frame])
    m = g + lo.offset[frame]
    P = F @ post.cov_alpha[p] @ np.swapaxes(F, 1, 2) + lo.cov_scale[frame, None, None] * (R3 @ lo.cov @ np.swapaxes(R3, 1, 2))
    for k, j in enumerate(idx):
        mk, Pk = m[k], P[k]
        for e in range(first[k], j):  # earlier sightings of the same frame (rare): applied first
            if batch.used[e]:
                h, H, rd = sighting_model(lo, mk[None], batch.sight_xy[e:e + 1], np.array([e]))
                v, S = ekf_innovation(Pk, h[0], H[0], np.diag(rd[0]), batch.sight_value[e], AIBO_ANGLE_MASK)
                mk, Pk = ekf_update(mk, Pk, H[0], np.diag(rd[0]), v, S)
        m[k], P[k] = mk, Pk
    h, H, rd = sighting_model(lo, m, batch.sight_xy[idx], idx)
    S = H @ P @ np.swapaxes(H, 1, 2)
    S[:, 0, 0] += rd[:, 0]
    S[:, 1, 1] += rd[:, 1]
    v = batch.sight_value[idx] - h
    v[:, 1] = geometry.wrap(v[:, 1])
    det = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0]
    m2 = (S[:, 1, 1] * v[:, 0] ** 2 - 2 * S[:, 0, 1] * v[:, 0] * v[:, 1] + S[:, 0, 0] * v[:, 1] ** 2) / det
    out[:] = -0.5 * (m2 + np.log(det) + 2.0 * np.log(2.0 * np.pi))
    return out


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
    heldout = float(np.sum(predictive_logdens(model.lower(batch), batch, post_all, idx)))
    n = len(idx)
    ok = np.isfinite(nis) & (nis <= DEFAULT_GATE)
    lo, hi = stats.chi2.ppf([0.025, 0.975], 2)
    z = nis[ok]
    seq = np.sqrt(z) - np.mean(np.sqrt(z))
    white = float(np.sum(seq[1:] * seq[:-1]) / np.sum(seq * seq)) if len(seq) > 2 else 0.0
    return Score(heldout, n, -heldout / max(n, 1), float(np.mean(z)),
                 float(np.mean((z < lo) | (z > hi))), white, nis)
