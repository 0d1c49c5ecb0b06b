"""The actuation-lag search after the fit of a continuous-command log (``EMOptions.lag_search``).

Velocity commands and the motion they cause are misaligned by the actuation lag (MRCLAM: ~0.25 s). A
model fitted without it regresses the motion on commands that changed too early, and the gain on a
command that changes often comes out attenuated (errors in variables): on MRCLAM robots 3 and 5 the
learned turn gain was 0.67-0.77 where Vicon says 0.93, and the model turned WORSE than the commands at
face value. So, for logs of continuous commands, the fit is refitted with ``actuation_lag`` frozen at
each value of its grid (``ActuationLag.GRID``), warm-started from the fit, on the fit's own sightings
(first-iteration outliers stay pruned, so the likelihoods compare), and the most likely lag is kept when
its likelihood-ratio test against the fit without it is significant (chi-square, 1 dof, p < ``ALPHA``). The fit
without it is refitted too, with the same budget and the stop rule of compared fits (``EMOptions.comparable``):
EM's own stop leaves a few nats on the table (issue 19's early stop), which a lag refit would otherwise collect.

The record goes into the model file's ``info["lag_search"]``: the grid, each refit's likelihood, the
lag kept (0 when none) and the nats gained.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

from learners.arrays.batch import Batch
from learners.em.fit import EMState, initial_state, run
from learners.em.options import EMOptions
from learners.model.catalogue import ActuationLag
from learners.model.model import Model

ALPHA = 0.01  # false-alarm level of keeping a lag
REFIT_ITER = 150  # EM iterations of each warm-started refit (the discrepancy search's grid refits use as many)


@dataclass
class LagSearch:
    best: Model
    loglik: float
    record: dict
    seconds: float


def applies(batch: Batch, model: Model, opts: EMOptions) -> bool:
    """Whether the search runs: continuous commands, the option on, and no lag in the model already."""
    return opts.lag_search and batch.controls is not None and model.effect("actuation_lag") is None


def search(batch: Batch, model: Model, loglik: float, opts: EMOptions) -> LagSearch:
    """Refit ``model`` (EM's best, of likelihood ``loglik`` on ``batch``) with each lag of the grid frozen;
    keep the most likely if significant (module docstring)."""
    t0 = time.perf_counter()
    refit = replace(opts.comparable(), frozen=opts.frozen + (ActuationLag.name,), gate=None, starts=1,
                    alias_search=False, lag_search=False, uncertainty=False, finish="none",
                    max_iter=min(opts.max_iter, REFIT_ITER))
    grid = [g for g in ActuationLag.GRID["lag_s"] if g > 0]
    tried = []
    for lag in [0.0, *grid]:  # lag 0: the null, refitted with the same budget (the fit stopped before converging)
        state: EMState = run(batch, initial_state(model.with_effect(ActuationLag(lag)), batch, refit), refit)
        tried.append((state.best_loglik, lag, state.best, state.iteration))
    (null_ll, *_), tried = tried[0], tried[1:]
    best_ll, best_lag, best_model, _ = max(tried, key=lambda t: t[0])
    gain = best_ll - max(loglik, null_ll)
    from scipy import stats  # here, not at import: scipy.stats costs every command ~1 s to load

    keep = 2.0 * gain > stats.chi2.ppf(1.0 - ALPHA, 1)
    record = {"grid_s": grid, "loglik": [t[0] for t in tried], "base_loglik": loglik, "null_loglik": null_ll,
              "lag_s": best_lag if keep else 0.0, "gain_nats": gain if keep else 0.0,
              "iterations": sum(t[3] for t in tried)}
    return LagSearch(best_model if keep else model, best_ll if keep else loglik, record, time.perf_counter() - t0)
