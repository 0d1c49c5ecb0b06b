"""One-step predictive densities of sightings: what the forward filter predicted for each, and the
model's density of it (a mixture when an effect says so, e.g. ``false_sightings``).

``sightings_logdens`` is the likelihood every comparison of models uses (the E-step's, the
held-out score's): for a model whose effects are all Gaussian it is exactly the E-step's
log-likelihood; an effect that is a mixture (``EffectModel.predictive_logdens``) turns each
sighting's Gaussian density into the mixture's, the filter itself being the Gaussian (assumed
density) one the kernels run.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from aibo_core import geometry
from learners.arrays.batch import Batch
from learners.arrays.innovations import Innovations
from learners.arrays.lowered import Lowered, sighting_model
from learners.arrays.posterior import Posterior
from learners.inference.reference import AIBO_ANGLE_MASK, ekf_innovation, ekf_update

if TYPE_CHECKING:
    from learners.model.model import Model


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
    p = batch.frame_to_pose[frame]
    g, F, R3 = geometry.motion(post.mu_alpha[p], lo.disp[frame])
    m = g + lo.offset[frame]
    P = F @ post.cov_alpha[p] @ np.swapaxes(F, 1, 2) + lo.cov_scale[frame, None, None] * (R3 @ lo.cov @ np.swapaxes(R3, 1, 2))
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
    return Innovations(v, np.stack([hph[:, 0, 0], 0.5 * (hph[:, 0, 1] + hph[:, 1, 0]), hph[:, 1, 1]], axis=1), rd)


def _augmented_innovations(lo: Lowered, batch: Batch, idx: np.ndarray, lo_own: Lowered) -> Innovations:
    """The innovations of sightings ``idx`` in the augmented forward filter (every used sighting applied, no gate):
    each one's prediction from the belief on (pose, extra states) before it, with the sighting's OWN noise
    (``lo_own``'s variance factors in place of the filter's)."""
    from learners.inference.kernels.estep import innovations_compiled

    _, innov = innovations_compiled(lo, batch)
    v0, v1, s00, s01, s11 = innov[idx].T
    hph = np.stack([s00 - lo.sigma_size ** 2 * lo.size_var_factor[idx], s01,
                    s11 - lo.sigma_bearing ** 2 * lo.bearing_var_factor[idx]], axis=1)
    r = np.stack([lo.sigma_size ** 2 * lo_own.size_var_factor[idx],
                  lo.sigma_bearing ** 2 * lo_own.bearing_var_factor[idx]], axis=1)
    return Innovations(np.stack([v0, v1], axis=1), hph, r)


def has_mixture(model: "Model") -> bool:
    """Whether an effect of ``model`` changes the sightings' densities (``EffectModel.predictive_logdens``)."""
    from learners.model.effects import EffectModel

    return any(type(e).predictive_logdens is not EffectModel.predictive_logdens for e in model.effects)


def sightings_logdens(model: "Model", batch: Batch, post: Posterior, idx: np.ndarray,
                      lo: Lowered | None = None) -> np.ndarray:
    """The model's one-step predictive log density of sightings ``idx`` (module docstring): the filter's
    Gaussian (``predictive_logdens``, each sighting's own noise from the effects' ``predictive()``
    versions), then every effect's ``predictive_logdens`` hook."""
    lo = model.lower(batch) if lo is None else lo
    return model_logdens(model, predictive_innovations(lo, batch, post, idx, own_noise(model, batch, lo)), batch, idx)


def own_noise(model: "Model", batch: Batch, lo: Lowered) -> Lowered:
    """The lowered arrays whose noise a sighting's OWN density uses: the effects' ``predictive()`` versions
    (``lo`` itself when no effect has one)."""
    own = tuple(e.predictive() for e in model.effects)
    return lo if all(a is b for a, b in zip(own, model.effects)) else replace(model, effects=own).lower(batch)


def model_logdens(model: "Model", innov: Innovations, batch: Batch, idx: np.ndarray) -> np.ndarray:
    """The model's log density of sightings ``idx`` from their innovations (their own noise in ``innov.r``): the
    Gaussian's, then every effect's ``predictive_logdens`` hook applied in turn, in ``DENSITY_ORDER`` (a scale mixture
    of the noise before a mixture with spurious sightings)."""
    out = innov.logdens()
    for e in sorted(model.effects, key=lambda e: e.DENSITY_ORDER):
        out = e.predictive_logdens(out, innov, batch, idx)
    return out
