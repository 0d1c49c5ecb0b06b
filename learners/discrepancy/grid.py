"""A grid candidate's profile likelihood (an effect with ``EffectModel.GRID``, e.g. ``actuation_lag``'s lag): one fit
per grid value, the effect held there, walked in the grid's order until the profile has passed its peak.

Each value's fit starts from the candidate's warm start, never from its neighbour's fit, so the points are independent
of each other and of the order they are computed in: the search (``learners.discrepancy.search``) runs them as jobs
of their own on the worker pool, a few ahead of the walk (:class:`GridWalk`), and keeps the points the walk in order
would have evaluated, the same fits and the same decisions as one process walking them (``tests/test_search_rules``).
On MRCLAM robot 3 the lag's profile, 36.5 s of one worker while the other finished the round's other candidates in
12 s, was the round's longest chain (docs/results.md, "Performance").
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from learners.em.estep import forward_loglik
from learners.em.uncertainty import CHI2_1_95
from learners.model.effects import EFFECT_MODELS
from learners.model.model import Model

from .candidate import Candidate
from .checks import tested
from .fitting import SearchContext, held, with_values

#: The walk stops at the first value this many nats below the best so far: a lag's profile rises to one peak and
#: falls (measured on MRCLAM robot 1 with bias states, in nats over no lag: 0, 246, 457, 371, 181, 15), and the values
#: past it, each a fit of up to 150 iterations, cannot win.
PAST_PEAK_NATS = 20.0


def walk_profile(grid: tuple[float, ...], loglik: Callable[[float], float]) -> list[float]:
    """``loglik`` at the grid's values in order, until one is ``PAST_PEAK_NATS`` below the best so far (the
    profile has passed its peak); the log-likelihoods evaluated, in grid order."""
    lls: list[float] = []
    for g in grid:
        lls.append(loglik(g))
        if stop_index(lls) is not None:
            break
    return lls


def stop_index(lls: list[float]) -> int | None:
    """Where :func:`walk_profile` stops on a profile whose first values are ``lls`` (in grid order): the first one
    ``PAST_PEAK_NATS`` below the best up to it; None when it would go on."""
    return next((k for k in range(len(lls)) if lls[k] < max(lls[:k + 1]) - PAST_PEAK_NATS), None)


def walked(lls: list[float]) -> int:
    """How many of ``lls`` :func:`walk_profile` evaluates: up to and with its stop (:func:`stop_index`), else all."""
    k = stop_index(lls)
    return len(lls) if k is None else k + 1


def candidate_start(name: str, ctx: SearchContext) -> Model:
    """The current model extended with effect ``name`` at its start, then its warm start (one forward pass each)."""
    batch = ctx.batch
    start = ctx.current.with_effect(EFFECT_MODELS[name].start(batch))
    return start.with_effect(start.effect(name).warm_start(start, batch, forward_loglik(batch)))


def grid_point(args: tuple[str, SearchContext, Model, float]) -> tuple[Model, float]:
    """(the fit, its training log-likelihood) of grid candidate ``name`` held at grid value ``g`` from ``start``. Each
    value's fit starts from the warm start, not from the previous value's fit (continuation): on the 5-minute log of
    seed 2005 with a 0.1 s lag, continuation reached the same training likelihood (-264.6 vs -265.0 nats) 47 nats worse
    held out, and the lag was not named (docs/results.md)."""
    name, ctx, start, g = args
    (pname, _), = EFFECT_MODELS[name].GRID.items()
    fit = ctx.fit(start.with_effect(with_values(start.effect(name), {pname: g})), held(ctx.opts, name))
    return fit, ctx.loglik(fit)


def below_first_step(start: Model, name: str, lls: list[float], ctx: SearchContext) -> float | None:
    """The value half way from the grid's neutral first value to its second, where the walked profile ``lls`` falls
    from that second value on and does not rise there significantly (the training likelihood's ratio, chi^2 with 1
    degree of freedom), and the parameter acts continuously (``EffectModel.grid_resolution`` None); else None.

    Why: as ``aibo learn``'s lag search (``learners.em.lag``), a lag of half the grid's step is as far from no lag as
    from the step, so neither fits it: on an independent generator's 5-minute log whose net lag is 0.05 s
    (``scripts/sensor_mount.py``'s robot, its camera stamped 0.05 s early) the walk gained +0.0 nats and named no lag,
    where ``aibo learn`` found 0.049 s (docs/results.md, "A lag below the grid's first step"). Discrete commands act in
    whole frames: their walk is unchanged."""
    (pname, grid), = EFFECT_MODELS[name].GRID.items()
    effect = start.effect(name)
    if effect.grid_resolution(pname, ctx.batch) is not None or len(lls) < 2:
        return None
    if float(np.asarray(effect.values()[pname])) != grid[0] or int(np.argmax(lls[1:])) != 0:
        return None
    return None if 2.0 * (lls[1] - lls[0]) > CHI2_1_95 else (grid[0] + grid[1]) / 2.0


def grid_candidate(name: str, ctx: SearchContext, start: Model, points: list[tuple[Model, float]]) -> Candidate:
    """The candidate of a walked profile (``points``: the grid's first values' fits, as :func:`walked` keeps them, and
    one more half a step in where :func:`below_first_step` says so): its best point, tested against the grid's neutral
    value's fit when it was walked (the same start and budget)."""
    (pname, grid), = EFFECT_MODELS[name].GRID.items()
    values, points = list(grid[:len(points)]), list(points)
    half = below_first_step(start, name, [ll for _, ll in points], ctx)
    if half is not None:
        values.insert(1, half)
        points.insert(1, grid_point((name, ctx, start, half)))
    lls = [ll for _, ll in points]
    k = int(np.argmax(lls))
    null = None
    neutral = float(np.asarray(start.effect(name).values()[pname]))
    if neutral in values:
        k0 = values.index(neutral)
        null = (lls[k0], ctx.heldout(points[k0][0]))
    c = tested(name, points[k][0], lls[k], ctx, null)
    c.start, c.profile = start, {pname: [values, lls]}
    return c


def profiled(name: str, ctx: SearchContext) -> Candidate:
    """Grid candidate ``name`` walked in this process, one value after another."""
    start = candidate_start(name, ctx)
    (_, grid), = EFFECT_MODELS[name].GRID.items()
    points: list[tuple[Model, float]] = []
    walk_profile(grid, lambda g: points.append(grid_point((name, ctx, start, g))) or points[-1][1])
    return grid_candidate(name, ctx, start, points)


@dataclass
class GridWalk:
    """A grid candidate's profile computed out of order (module docstring): ``next_value`` hands out the grid's values
    in order while the walk may still need them, ``record`` takes a value's point, ``done`` says when the points
    in hand settle the walk."""

    name: str
    ctx: SearchContext
    start: Model
    points: dict[int, tuple[Model, float]] = field(default_factory=dict)
    handed: int = 0  # grid values handed out so far

    @property
    def grid(self) -> tuple[float, ...]:
        (_, grid), = EFFECT_MODELS[self.name].GRID.items()
        return grid

    def _prefix(self) -> list[float]:
        """The log-likelihoods of the grid's first values that have all arrived."""
        lls = []
        while len(lls) in self.points:
            lls.append(self.points[len(lls)][1])
        return lls

    def done(self) -> bool:
        lls = self._prefix()
        return len(lls) == len(self.grid) or stop_index(lls) is not None

    def next_value(self) -> int | None:
        """The index of the next grid value to compute, or None when the walk needs no more."""
        if self.done() or self.handed >= len(self.grid):
            return None
        self.handed += 1
        return self.handed - 1

    def record(self, k: int, point: tuple[Model, float]) -> None:
        self.points[k] = point

    def candidate(self) -> Candidate:
        lls = self._prefix()
        return grid_candidate(self.name, self.ctx, self.start, [self.points[k] for k in range(walked(lls))])
