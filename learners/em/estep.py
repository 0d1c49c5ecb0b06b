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
