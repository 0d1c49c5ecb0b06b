"""The forward filter's one-step predictions of the sightings as innovations (``learners.arrays.innovations``): what
each sighting's predictive density is made of. Pure functions of (lowered model, batch, posterior); the model's own
density of a sighting (a mixture's, where an effect says so) is ``learners.em.predictive``'s."""

from __future__ import annotations

import numpy as np

from aibo_core import geometry
from learners.arrays.batch import Batch
from learners.arrays.innovations import Innovations, pose_prediction
from learners.arrays.lowered import Lowered, sighting_model
from learners.arrays.posterior import Posterior
from learners.inference.reference import AIBO_ANGLE_MASK, ekf_innovation, ekf_update


def predictive_logdens(lo: Lowered, batch: Batch, post: Posterior, idx: np.ndarray,
                       lo_own: Lowered | None = None) -> np.ndarray:
    """log N(z_j; h(m-), H P- H^T + R) of sightings ``idx``: ``predictive_innovations(...).logdens()``."""
    return predictive_innovations(lo, batch, post, idx, lo_own).logdens()


def predictive_innovations(lo: Lowered, batch: Batch, post: Posterior, idx: np.ndarray,
                           lo_own: Lowered | None = None) -> Innovations:
    """The innovations of sightings ``idx`` in the forward filter: each one's prediction from the filtered belief at
    the start of its frame (mu_alpha, cov_alpha), the motion of the frame, and the frame's earlier sightings applied
    in order (as the E-step does). ``lo_own``: the lowered arrays whose noise R the sighting's OWN density uses
    (default ``lo``; an effect may inflate a sighting's variance in the filter from the sighting itself, e.g. by its
    responsibility, which its own density must not see)."""
    lo_own = lo if lo_own is None else lo_own
    if lo.extra is not None:  # extra states change the prediction: the augmented forward filter's own innovations
        return _augmented_innovations(lo, batch, idx, lo_own)
    frame = batch.sight_frame[idx]
    first = batch.sight_start[frame]
    m, P = pose_prediction(lo, batch, post, frame)
    for k in np.flatnonzero(first < idx):  # earlier sightings of the same frame (rare): applied first
        mk, Pk = m[k], P[k]
        for e in range(first[k], idx[k]):
            if batch.used[e]:
                h, H, rd = sighting_model(lo, mk[None], batch.sight_xy[e:e + 1], np.array([e]))
                v, S = ekf_innovation(Pk, h[0], H[0], np.diag(rd[0]), batch.sight_value[e], AIBO_ANGLE_MASK)
                mk, Pk = ekf_update(mk, Pk, H[0], np.diag(rd[0]), v, S)
        m[k], P[k] = mk, Pk
    h, H, rd = sighting_model(lo_own, m, batch.sight_xy[idx], idx)
    hph = H @ P @ np.swapaxes(H, 1, 2)
    v = batch.sight_value[idx] - h
    v[:, 1] = geometry.wrap(v[:, 1])
    return Innovations(v, hph, rd)


def _augmented_innovations(lo: Lowered, batch: Batch, idx: np.ndarray, lo_own: Lowered) -> Innovations:
    """The innovations of sightings ``idx`` in the augmented forward filter (every used sighting applied, no gate):
    each one's prediction from the belief on (pose, extra states) before it, with the sighting's OWN noise
    (``lo_own``'s variance factors in place of the filter's)."""
    from learners.inference.kernels.estep import innovations_compiled

    _, innov = innovations_compiled(lo, batch)
    v0, v1, s00, s01, s11 = innov[idx].T
    hph = np.empty((len(idx), 2, 2))
    hph[:, 0, 0] = s00 - lo.sigma_size ** 2 * lo.size_var_factor[idx]
    hph[:, 0, 1] = hph[:, 1, 0] = s01
    hph[:, 1, 1] = s11 - lo.sigma_bearing ** 2 * lo.bearing_var_factor[idx]
    r = np.stack([lo.sigma_size ** 2 * lo_own.size_var_factor[idx],
                  lo.sigma_bearing ** 2 * lo_own.bearing_var_factor[idx]], axis=1)
    return Innovations(np.stack([v0, v1], axis=1), hph, r)
