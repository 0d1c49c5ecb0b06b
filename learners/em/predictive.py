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

from learners.arrays.batch import Batch
from learners.arrays.innovations import Innovations
from learners.arrays.lowered import Lowered
from learners.arrays.posterior import Posterior
from learners.inference.predictive import predictive_innovations

if TYPE_CHECKING:
    from learners.model.model import Model


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
