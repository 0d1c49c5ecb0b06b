"""The E-step of a fit: the lowered model's smoother on the batch (compiled kernels, or the NumPy reference), and the
likelihood of a mixture's sightings when an effect makes them non-Gaussian. A pure function of (model, data): the
fit, the discrepancy search, the scores and the benches import it from here."""

from __future__ import annotations

from typing import Callable

import numpy as np

from learners.arrays.batch import Batch
from learners.arrays.lowered import Lowered
from learners.arrays.posterior import Posterior
from learners.model.model import Model


def forward_loglik(batch: Batch) -> Callable[[Model], float]:
    """A model's log-likelihood (nats) of ``batch``'s sightings, one compiled forward pass (no smoothing): what an
    effect's ``warm_start`` compares its candidates by."""
    from learners.inference.kernels.estep import innovations_compiled

    return lambda model: float(innovations_compiled(model.lower(batch), batch)[0])


def e_step(params: Model, batch: Batch, estep: str, gate: float | None = None,
           reuse: Posterior | None = None, lo: Lowered | None = None) -> Posterior:
    """The E-step; ``reuse``: a spent Posterior whose memory the compiled kernel may overwrite;
    ``lo``: ``params.lower(batch)`` if the caller has it.

    When an effect of ``params`` is a mixture (``false_sightings``), the Posterior's ``loglik`` is
    the mixture's one-step predictive log-likelihood (``learners.em.predictive``), not the
    Gaussian filter's: the likelihood EM keeps the best of and the search compares."""
    lo = params.lower(batch) if lo is None else lo
    if estep == "compiled":
        from learners.inference.kernels import smooth_compiled

        post = smooth_compiled(lo, batch, gate, out=reuse)
    elif lo.extra is not None:
        from learners.inference.augmented import smooth_augmented

        post = smooth_augmented(lo, batch, gate)
    else:
        from learners.inference.reference import smooth

        post = smooth(lo, batch, gate)
    from learners.em.predictive import has_mixture, sightings_logdens

    if has_mixture(params):
        idx = np.flatnonzero(batch.used & ~(post.mahal2 > (gate if gate is not None else np.inf)))
        post.loglik = float(np.sum(sightings_logdens(params, batch, post, idx, lo)))
    return post


#: E-steps of :func:`weighed_on` (each followed by the weights at its smoothed path). Measured on the 5-minute
#: ``aibo`` log of seed 8002 with 8% spurious sightings, the search's ``false_sightings`` fitted in a world that fits
#: the field: held-out gain -4,661 nats unweighed, +7,243 with 3 (docs/results.md, "Spurious sightings: the search's
#: second start").
WEIGH_STEPS = 3


def weighed_on(model: "Model", batch: Batch) -> "Model":
    """``model`` with each noise mixture's per-sighting weights (``WeighedSightings``: what the Gaussian filter divides
    a sighting's variances by) computed on ``batch`` where its fit computed them on another batch (a held-out score's
    whole logs, fitted on their training halves): ``WEIGH_STEPS`` times the E-step and each mixture's weights at its
    smoothed path, the parameters held, as EM's M-step computes them. Without them the filter takes every sighting at
    full weight and, in a world that fits the field, spurious sightings drag its pose."""
    from learners.model.catalogue_more import WeighedSightings

    stale = [e for e in model.effects if isinstance(e, WeighedSightings) and not e.weighs(batch)]
    if not stale:
        return model
    for _ in range(WEIGH_STEPS):
        post = e_step(model, batch, "compiled")
        for e in stale:
            model = model.with_effect(model.effect(e.name).weighed(model, batch, post))
    return model
