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

Where no lag of the grid is significant and the grid's first step is its most likely, one more refit half that step
in (0.05 s): a lag there is as far from no lag as from the first step, so the grid alone cannot see it (docs/results.md,
"A lag below the grid's first step"); it is kept by the same test.

A kept lag is then refined between the grid's values (the commands are continuous, so the lag is too:
``ActuationLag`` averages the held commands over a frame): two more refits half a grid step either side of the
best, a parabola through the five refits nearest it, a last refit at its vertex (kept when more likely), and the
95% interval where the parabola drops 1.92 nats (chi-square(1, 0.95) / 2) below its top. A parabola that is not
concave there gives the grid's neighbours as the interval, said in the record's ``interval_note``.

The record goes into the model file's ``info["lag_search"]``: the grid, each refit's likelihood, the
lag kept (0 when none), its 95% interval and the refits that placed it, and the nats gained.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from learners.arrays.batch import Batch
from learners.em.fit import EMState, initial_state, run
from learners.em.options import EMOptions
from learners.em.uncertainty import CHI2_1_95
from learners.model.catalogue import ActuationLag
from learners.model.model import Model

ALPHA = 0.01  # false-alarm level of keeping a lag
HALF_CHI2_1_95 = CHI2_1_95 / 2.0  # nats: the drop that bounds a 95% profile interval
#: The lags refitted (s), walked in order until two in a row fall past the best: the catalogue's grid (``aibo
#: diagnose`` profiles over ``ActuationLag.GRID``, 0-0.5 s) and on to 1 s, so a log whose commands are stamped
#: early still finds its lag.
GRID_S = tuple(round(0.1 * k, 1) for k in range(11))
#: the interval note where the most likely refit lies outside the parabola's interval (docs/results.md, "An interval
#: that ends at its estimate": the kinked profile's own interval held known shifts of the commands less often)
WIDENED = ("widened to hold the most likely refit, which lies on a whole frame's kink of the profile, off the parabola "
           "through the refits")
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
    refit_opts = replace(opts.comparable(), frozen=opts.frozen + (ActuationLag.name,), gate=None, starts=1,
                    alias_search=False, lag_search=False, uncertainty=False, finish="none",
                    max_iter=min(opts.max_iter, REFIT_ITER))
    grid = []
    tried = []
    for lag in GRID_S:  # lag 0: the null, refitted with the same budget (the fit stopped before converging)
        state: EMState = run(batch, initial_state(model.with_effect(ActuationLag(lag)), batch, refit_opts), refit_opts)
        tried.append((state.best_loglik, lag, state.best, state.iteration))
        grid += [lag] if lag > 0 else []
        lls = [t[0] for t in tried]
        if len(lls) >= 3 and lls[-1] < lls[-2] < max(lls) - HALF_CHI2_1_95:  # past the peak: the rest only falls
            break
    (null_ll, *_), grid_tried = tried[0], tried[1:]
    best_ll, best_lag, best_model, _ = max(grid_tried, key=lambda t: t[0])
    gain = best_ll - max(loglik, null_ll)
    from scipy import stats  # here, not at import: scipy.stats costs every command ~1 s to load

    threshold = stats.chi2.ppf(1.0 - ALPHA, 1)
    step = min(g2 - g1 for g1, g2 in zip([0.0, *grid], grid))

    def refit(lag: float, start: Model) -> tuple:
        state = run(batch, initial_state(start.with_effect(ActuationLag(lag)), batch, refit_opts), refit_opts)
        tried.append((state.best_loglik, lag, state.best, state.iteration))
        return tried[-1]

    below = None
    if not 2.0 * gain > threshold and best_lag == grid[0]:
        # no lag of the grid is significant and the likelihood falls from its first step on: a lag below that step
        # may be, half a step being as far from no lag as from the step (an independent generator's log with 50 ms:
        # none found, the smoothed pose 19.9 mm from the truth, 14.9 mm with the lag at 0.1 s; docs/results.md, "A
        # lag below the grid's first step")
        below = refit(step / 2, tried[0][2])
        if below[0] > best_ll:
            best_ll, best_lag, best_model, _ = below
            gain = best_ll - max(loglik, null_ll)
    keep = 2.0 * gain > threshold
    record = {"grid_s": grid, "loglik": [t[0] for t in grid_tried], "base_loglik": loglik, "null_loglik": null_ll,
              "lag_s": best_lag if keep else 0.0, "gain_nats": gain if keep else 0.0,
              "iterations": sum(t[3] for t in tried)}
    if below is not None:
        record["below_grid"] = [below[1], below[0]]  # [lag s, loglik] of the refit half a step in
    if not keep:
        return LagSearch(model, loglik, record, time.perf_counter() - t0)

    done = {t[1] for t in tried}
    for lag in (best_lag - step / 2, best_lag + step / 2):
        if lag > 0 and not any(abs(lag - d) < 1e-9 for d in done):
            refit(lag, best_model)
    lag, interval, note = refine(sorted((t[1], t[0]) for t in tried), best_lag, step)
    if lag not in {t[1] for t in tried}:
        refit(lag, best_model)
    best_ll, best_lag, best_model, _ = max(tried, key=lambda t: t[0])
    # the most likely refit may sit just off the parabola's interval (the profile has a kink at each whole frame,
    # where the averaged commands change pairs): the interval is widened to hold the lag reported
    interval, note = holding(interval, best_lag, note)
    record.update(lag_s=best_lag, gain_nats=best_ll - max(loglik, null_ll), interval_95=interval,
                  interval_note=note, refits=[[t[1], t[0]] for t in sorted(tried, key=lambda t: t[1])],
                  iterations=sum(t[3] for t in tried))
    return LagSearch(best_model, best_ll, record, time.perf_counter() - t0)


def holding(interval: list[float], value: float, note: str) -> tuple[list[float], str]:
    """``interval`` widened to hold ``value`` (the most likely refit, off the parabola's interval where it lies on a
    whole frame's kink), and ``note`` with ``WIDENED`` added where it was."""
    if interval[0] <= value <= interval[1]:
        return interval, note
    return [min(interval[0], value), max(interval[1], value)], "; ".join(n for n in (note, WIDENED) if n)


def refine(points: list[tuple[float, float]], best: float, step: float) -> tuple[float, list[float], str]:
    """(vertex, [low, high] 95% interval, note) of the parabola through the (lag s, loglik) ``points`` within one
    grid ``step`` of ``best`` (module docstring); the vertex clipped to that neighbourhood. Not concave, or too few
    points: ``best`` and the neighbouring grid values, with a note saying so."""
    near = [(x, y) for x, y in points if abs(x - best) <= step + 1e-9]
    lo_end, hi_end = max(best - step, 0.0), best + step
    if len(near) >= 3:
        c2, c1, _ = np.polyfit([x - best for x, _ in near], [y for _, y in near], 2)
        if c2 < 0:
            top = float(np.clip(best - c1 / (2.0 * c2), lo_end, hi_end))
            half = math.sqrt(HALF_CHI2_1_95 / -c2)
            return top, [max(top - half, 0.0), top + half], ""
    return best, [lo_end, hi_end], "the likelihood is not concave about the best grid value: its grid neighbours"
