"""Whether a model's size errors are white: the lag-1 autocorrelation of the normalized size innovations
v_size / sqrt(S00) of the forward filter over consecutive sightings of one landmark at most ``pair_s``
seconds apart (within one log). Measured on the five MRCLAM robots: 0.72-0.89 for the models without bias
states (range errors that drift per landmark, issue 17), 0.05-0.20 with ``landmark_bias``; about 0 on
simulated logs without a bias."""

from __future__ import annotations

import numpy as np

from learners.arrays.batch import Batch
from learners.model.model import Model

PAIR_S = 2.0  # s: the longest gap between two sightings of one landmark that still make a pair
CLIP = 5.0  # normalized innovations beyond this in magnitude (gross outliers) are left out


def normalized_innovations(model: Model, batch: Batch) -> np.ndarray:
    """(S, 2) v_size / sqrt(S00) and v_bearing / sqrt(S11) of the forward filter (NaN where a sighting was not
    applied)."""
    from learners.inference.kernels import innovations_compiled

    _, innov = innovations_compiled(model.lower(batch), batch)
    return np.stack([innov[:, 0] / np.sqrt(innov[:, 2]), innov[:, 1] / np.sqrt(innov[:, 4])], axis=1)


def normalized_size_innovations(model: Model, batch: Batch) -> np.ndarray:
    """(S,) v_size / sqrt(S00) of the forward filter (NaN where a sighting was not applied)."""
    return normalized_innovations(model, batch)[:, 0]


def consecutive_pairs(batch: Batch, z: np.ndarray, pair_s: float = PAIR_S, clip: float = CLIP) -> np.ndarray:
    """(n, 2): ``z`` of consecutive sightings of the same landmark in the same log at most ``pair_s`` s apart
    (the used sightings with |z| < ``clip``)."""
    ok = np.flatnonzero(np.asarray(batch.used, bool) & np.isfinite(z) & (np.abs(z) < clip))
    idx, gap = _landmark_runs(batch, ok)
    close = gap <= pair_s
    return np.stack([z[idx[:-1][close]], z[idx[1:][close]]], axis=1)


def _landmark_runs(batch: Batch, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the sightings ``ok`` ordered by landmark, then log, then frame; (len - 1,) the time (s) from each to the next
    where that is the same landmark in the same log, inf where it is not)."""
    frame = batch.sight_frame
    log = np.searchsorted(batch.frame_start, frame, side="right") - 1
    idx = ok[np.lexsort((frame[ok], log[ok], batch.sight_landmark[ok]))]
    same = (np.diff(batch.sight_landmark[idx]) == 0) & (np.diff(log[idx]) == 0)
    return idx, np.where(same, np.diff(frame[idx]) * batch.dt, np.inf)


def since_last_sighting(batch: Batch) -> np.ndarray:
    """(S,) the time (s, whole frames) since the previous sighting of the same landmark in the same log, inf for a
    landmark's first (every sighting, used or not)."""
    idx, gap = _landmark_runs(batch, np.arange(batch.n_sightings))
    out = np.full(batch.n_sightings, np.inf)
    out[idx[1:]] = gap
    return out


def lag1(pairs: np.ndarray) -> float:
    """Pearson correlation of the pairs (the lag-1 autocorrelation); NaN with fewer than 3 pairs."""
    return float(np.corrcoef(pairs[:, 0], pairs[:, 1])[0, 1]) if len(pairs) >= 3 else float("nan")


def size_error_lag1(model: Model, batch: Batch, pair_s: float = PAIR_S) -> tuple[float, int]:
    """(lag-1 autocorrelation of ``model``'s normalized size innovations on ``batch``, number of pairs)."""
    pairs = consecutive_pairs(batch, normalized_size_innovations(model, batch), pair_s)
    return lag1(pairs), len(pairs)
