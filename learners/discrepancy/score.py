"""Scores of a model on data: the held-out predictive log-likelihood (the gap), the held-out open-loop
predictive log-likelihood over seconds (the motion gap), and the consistency of the innovations (normalized
innovation squared against its chi-square band, and whiteness)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from aibo_core.trajectory import Trajectory
from learners.arrays.batch import make_batch
from learners.em.estep import e_step, weighed_on
from learners.em.options import DEFAULT_GATE
from learners.em.predictive import model_logdens, own_noise, sightings_logdens
from learners.em.starts import start_beliefs
from learners.em.whiteness import consecutive_pairs, lag1, normalized_innovations
from learners.inference.open_loop import open_loop_innovations
from learners.inference.predictive import predictive_logdens
from learners.model.model import Model

from .split import heldout_mask

GAP_METRIC = "heldout_nll_per_sighting"
#: ``Score.whiteness``, the one autocorrelation the report, the README and ``aibo learn``'s warning quote
#: (``learners.em.whiteness``): consecutive sightings of one landmark at most 2 s apart.
WHITENESS_METRIC = "lag-1 autocorrelation of the normalized size innovations, per landmark"
#: The motion gap: each held-out sighting predicted open loop from the filtered pose k seconds before it
#: (``learners.inference.open_loop``), negative log density per sighting, at each horizon k (s).
MOTION_GAP_METRIC = "heldout_open_loop_nll_per_sighting"
MOTION_HORIZONS_S = (1.0, 2.0, 5.0)
#: Time blocks (s) over which a motion gap's paired difference is summed before its standard error: open-loop
#: errors of sightings a few seconds apart share the same stretch of motion, so they are not independent.
MOTION_BLOCK_S = 30.0
#: The chi-square(2) 95% band of the NIS (both sides): ``Score.nis_outside`` counts the sightings outside it
NIS_BAND = tuple(float(x) for x in stats.chi2.ppf([0.025, 0.975], 2))
__all__ = ["GAP_METRIC", "WHITENESS_METRIC", "MOTION_GAP_METRIC", "MOTION_HORIZONS_S", "NIS_BAND", "MotionScore", "Score",
           "motion_score", "motion_trade", "predictive_logdens", "score"]


@dataclass
class Score:
    """How well a model predicts the logs."""

    heldout_loglik: float  # log p(held-out sightings | training sightings), nats
    n_heldout: int
    gap: float  # GAP_METRIC: -heldout_loglik / n_heldout (nats per sighting; lower is better)
    nis_mean: float  # mean normalized innovation squared (2 expected: 2-d sightings)
    nis_outside: float  # share outside the chi-square(2) 95% band (0.05 expected)
    nis_median: float  # median NIS (chi-square(2): 2 log 2 = 1.386 expected)
    whiteness: float  # WHITENESS_METRIC (0 expected)
    bearing_whiteness: float  # the same of the normalized bearing innovations (0 expected; per-landmark bearing biases)
    nis: np.ndarray  # (S,) per sighting, NaN where gated

    def as_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in self.__dict__.items() if k != "nis"}


def score(model: Model, logs: list[Trajectory], gate: float | None = None) -> Score:
    """The held-out one-step predictive log-likelihood: the sum, over the held-out sightings, of the
    log density the forward filter (run over all sightings, the model fitted on the training half)
    predicted for each. ``gate``: leave out sightings whose Mahalanobis^2 exceeds it (default none:
    the caller removed outliers once for all models)."""
    batch = make_batch(logs)
    model = weighed_on(model, batch)  # a mixture's weights on these logs (its fit's are the training halves')
    held = np.concatenate([heldout_mask(tr) for tr in logs])
    post_all = e_step(model, batch, "compiled", gate)
    nis = np.array(post_all.mahal2, copy=True)
    idx = np.flatnonzero(held & batch.used & ~(nis > (gate if gate is not None else np.inf)))
    heldout = float(np.sum(sightings_logdens(model, batch, post_all, idx)))
    n = len(idx)
    ok = np.isfinite(nis) & (nis <= DEFAULT_GATE)
    lo, hi = NIS_BAND
    z = nis[ok]
    normalized = normalized_innovations(model, batch)
    white, white_b = (lag1(consecutive_pairs(batch, normalized[:, c])) for c in (0, 1))
    return Score(heldout, n, -heldout / max(n, 1), float(np.mean(z)), float(np.mean((z < lo) | (z > hi))),
                 float(np.median(z)) if len(z) else float("nan"), white if np.isfinite(white) else 0.0,
                 white_b if np.isfinite(white_b) else 0.0, nis)


#: z of the motion gap's paired change (after - before, block standard error; ``motion_trade``) beyond which a model
#: is said to make the motion worse: one-sided 2.3% if the change were noise alone
MOTION_WORSE_Z = 2.0


def horizon_key(seconds: float) -> str:
    """The key of a horizon in ``report.json`` (seconds, shortest form: "1", "2", "0.5")."""
    return f"{seconds:g}"


@dataclass
class MotionScore:
    """A model's held-out open-loop log densities, per horizon: what its motion is judged by."""

    idx: np.ndarray  # (n,) the held-out sightings scored (indices into the batch of the logs)
    time_s: np.ndarray  # (n,) each one's time in its log (s)
    log: np.ndarray  # (n,) each one's log index
    logdens: dict[str, np.ndarray]  # horizon key -> (n,) log density, NaN where its log began within the horizon
    one_step: np.ndarray  # (n,) the one-step predictive log density of the same sightings (the gap's)

    def gap(self) -> dict[str, float]:
        """MOTION_GAP_METRIC per horizon key: negative mean log density of the sightings scored at it."""
        return {k: float(-np.nanmean(v)) if np.isfinite(v).any() else float("nan") for k, v in self.logdens.items()}

    def excess(self) -> dict[str, float]:
        """Per horizon key: the motion gap less the one-step gap of the same sightings (nats per sighting): what
        the model loses when its motion, not the last sighting, has to carry the pose for that long. Descriptive: a
        tighter sensor model makes the same pose error cost more nats, so the excess grows with it too."""
        return {k: float(np.nanmean(self.one_step - v)) if np.isfinite(v).any() else float("nan")
                for k, v in self.logdens.items()}


def motion_score(model: Model, logs: list[Trajectory], horizons_s: tuple[float, ...] = MOTION_HORIZONS_S,
                 heldout_only: bool = True, own_start: bool = True) -> MotionScore:
    """The held-out sightings (``heldout_mask``, the used ones; every used one with ``heldout_only`` False, for
    logs the model was not fitted to, whose start beliefs are then the logs' own, ``learners.em.starts.start_beliefs``,
    unless ``own_start`` is False) predicted open loop from the filtered belief k seconds before each (the forward
    filter run over all sightings with ``model``, as ``score`` does) and the commands alone, for each horizon k; the
    model's own density of each (a mixture's where an effect says so)."""
    batch = make_batch(logs)
    if not heldout_only and own_start:  # logs the model was not fitted to: its init is another run's start
        model = model.with_(init=start_beliefs(model, logs))
    model = weighed_on(model, batch)  # as ``score``
    post = e_step(model, batch, "compiled", None)
    lo = model.lower(batch)
    lo_own = own_noise(model, batch, lo)
    held = np.concatenate([heldout_mask(tr) for tr in logs]) if heldout_only else True
    idx = np.flatnonzero(held & batch.used)
    frame = batch.sight_frame[idx]
    log = np.searchsorted(batch.frame_start, frame, side="right") - 1
    out = {}
    for h in horizons_s:
        ok, innov = open_loop_innovations(lo, batch, post, idx, max(1, int(round(h / batch.dt))), lo_own)
        ll = np.full(len(idx), np.nan)
        ll[ok] = model_logdens(model, innov, batch, idx[ok])
        out[horizon_key(h)] = ll
    one = sightings_logdens(model, batch, post, idx, lo)
    return MotionScore(idx, (frame - batch.frame_start[log] + 1) * batch.dt, log, out, one)


def _paired(d: np.ndarray, block: np.ndarray) -> tuple[float, float, float]:
    """(mean, standard error, z) of per-sighting differences ``d`` (NaN: left out), the standard error from
    their sums over ``block`` (the ratio estimator's, blocks of unequal size)."""
    ok = np.isfinite(d)
    n = int(ok.sum())
    if n == 0:
        return float("nan"), float("nan"), float("nan")
    _, inv = np.unique(block[ok], return_inverse=True)
    sums, counts = np.bincount(inv, weights=d[ok]), np.bincount(inv)
    g = len(sums)
    mean = float(d[ok].mean())
    resid = sums - mean * counts
    se = float(np.sqrt(g / (g - 1) * np.sum(resid * resid)) / n) if g > 1 else float("nan")
    return mean, se, (mean / se if np.isfinite(se) and se > 0 else float("nan"))


def motion_trade(before: MotionScore, after: MotionScore, block_s: float = MOTION_BLOCK_S) -> dict[str, dict]:
    """Per horizon key, paired on the same sightings (positive: ``after`` predicts worse): ``change`` of the
    motion gap and of its ``excess`` over the one-step gap (``MotionScore.excess``), nats per sighting, each with
    its standard error from the sums over ``block_s`` time blocks of each log (sightings whose errors share a
    stretch of motion) and z; ``n`` the sightings scored."""
    if not np.array_equal(before.idx, after.idx):
        raise ValueError("motion scores of different sightings")
    out = {}
    block = after.log * 10**6 + np.floor(after.time_s / block_s).astype(np.int64)
    for key, la in after.logdens.items():
        lb = before.logdens[key]
        change, se, z = _paired(lb - la, block)
        ex, ex_se, ex_z = _paired((after.one_step - la) - (before.one_step - lb), block)
        out[key] = {"change": change, "se": se, "z": z, "excess_change": ex, "excess_se": ex_se, "excess_z": ex_z,
                    "n": int(np.isfinite(la).sum())}
    return out
