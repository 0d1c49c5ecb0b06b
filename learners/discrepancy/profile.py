"""Profile-likelihood intervals for a named effect's one scalar parameter, on the whole logs.

A Wald interval (value +- 1.96 SE, ``effect_sizes``) assumes a quadratic log-likelihood. Where it crosses the
parameter's domain (a rate near 0) it is clipped and only a guide, and where the information does not determine
the parameter there is none. There the 95% profile-likelihood interval is the honest one: the values v whose fit with
the effect held at v (everything else refitted, warm-started from the diagnosed model) is within
chi-square(1, 0.95) / 2 = 1.92 nats of the best fit.

``profile_bounds`` walks out from the estimate on each side in steps that double (the first is the standard error,
or a tenth of the value's scale without one) until the profile drops more than 1.92 nats or the domain ends, then
bisects the last step ``BISECTIONS`` times: an end is good to 1/2**BISECTIONS of its bracket. Each point is one EM
fit (the search's stop rule, at most ``fitting.HELD_MAX_ITER`` iterations); a side costs 2-8 fits. The likelihood compared is
the E-step's on the logs' sightings (``fitting.train_loglik``), the same for every point. The two sides walk side by
side (``walk_in_step``), each round's points fitted at once in ``aibo diagnose``'s worker pool (``HeldFits``), as are
a Wald interval's two ends and a parabola's four points: the fits are deterministic, so the pool changes the wall
time, not the interval (a side reads the best of both sides' points so far).

A Wald interval inside the domain is checked (``check_wald_intervals``): two fits held at its ends (``wald_ends``).
Where one is less than 1.92 nats below the best the profile is flatter than the information says and the interval
becomes the profile one; where one beats the final fit, the final fit stopped short of the maximum, and the walk goes
on from that end while the likelihood rises (``climb``), its best value returned for the final fit to be made again.

Only effects with exactly one scalar parameter and no per-batch state qualify (``profiled_parameter``): freezing is
per effect (``EMOptions.frozen``), so holding one of several parameters would need per-parameter freezing.

A grid parameter (a lag: ``EffectModel.GRID``) has the search's grid profile on the training halves; its interval is
redone on the whole logs below the grid (``refine_grid_intervals``): where the logs resolve it in steps (a lag of
discrete commands acts in whole frames) the fits held at each step are walked out from the value (``step_walk``,
``lattice_interval``); where it acts continuously, a parabola through fits held at the value +- half and one grid
step (``parabola_interval``, ``aibo learn``'s lag interval).

An effect with one scalar parameter AND per-batch state (``false_sightings``' rate and its responsibilities: held, the
state would go stale) gets the conditional likelihood interval instead (``conditional_interval``): the values v whose
log-likelihood on the whole logs, everything else (its state included) held at the diagnosed model's values, is
within 1.92 nats of the best. It is one E-step per point, and narrower than the profile one would be by what the
other parameters could absorb (said in the entry's ``method``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import replace
from typing import Any, Callable, Generator

import numpy as np

from aibo_core.trajectory import Trajectory
from aibo_core.workers import pool_map
from learners.discrepancy.effect_sizes import CHI2_1_95
from learners.em.options import EMOptions
from learners.model.effects import EFFECT_MODELS
from learners.model.model import Model

HALF_CHI2_1_95 = CHI2_1_95 / 2.0  # nats: the drop that bounds a 95% profile-likelihood interval
BISECTIONS = 4  # per end, after the bracket is found
MAX_STEPS = 8  # steps per side before giving up (the end is then the farthest tried, reported as open)
BEATEN_NATS = 0.5  # a held fit this much more likely than the diagnosed one is reported (EM's stop rule: 0.1 nat)
#: the end of an interval's ``note`` when a held fit beat the diagnosed model (``aibo diagnose`` warns of it)
NOT_THE_MAXIMUM = "its fit may not be the maximum"


def profiled_parameter(name: str) -> str | None:
    """The one scalar, non-grid parameter of effect ``name`` a profile can hold, or None. Not for an effect that
    carries per-batch state besides its parameter (a dataclass field with ``compare=False``, e.g.
    ``false_sightings``' responsibilities): its own M-step recomputes that state, and held, it would go stale."""
    cls = EFFECT_MODELS[name]
    if len(cls.PARAMS) != 1 or cls.GRID or any(not f.compare for f in dataclasses.fields(cls)):
        return None
    (pname, param), = cls.PARAMS.items()
    return pname if param.shape == () else None


def conditional_parameter(name: str) -> str | None:
    """The one scalar, non-grid parameter of effect ``name`` that carries per-batch state besides it (so that
    ``profiled_parameter`` refuses it) and gets the conditional likelihood interval (module docstring), or None."""
    cls = EFFECT_MODELS[name]
    if profiled_parameter(name) is not None or len(cls.PARAMS) != 1 or cls.GRID:
        return None
    (pname, param), = cls.PARAMS.items()
    return pname if param.shape == () else None


def wants_profile(entry: dict) -> bool:
    """Whether an interval entry (``effect_sizes.effect_intervals``) of a ``profiled_parameter`` is one a Wald
    interval cannot be trusted for: no standard error, or an interval clipped at the parameter's domain (a grid
    parameter's entry has no standard error either, but ``profiled_parameter`` never names one)."""
    return entry.get("se") is None or bool(entry.get("clipped"))


def bracket_side(value: float, side: float, step: float, bound: float,
                 drop: float) -> Generator[float, tuple[float, float], tuple[float, bool]]:
    """One side of ``profile_bounds`` as a walk (``walk_in_step``): from ``value`` towards ``bound`` (``side`` -1 or
    +1) in steps from ``step`` that double until a point drops more than ``drop`` below the best or the domain ends,
    then ``BISECTIONS`` bisections of the last step. Returns (the end, open: still within ``drop`` there)."""
    inside, outside, d = value, None, step
    for _ in range(MAX_STEPS):
        v = value + side * d
        if (v - bound) * side >= 0:  # at or past the domain's end: try the end itself
            v = bound
        ll, best = yield v
        if ll < best - drop:
            outside = v
            break
        inside = v
        if v == bound:
            break
        d *= 2.0
    if outside is None:
        return inside, True
    for _ in range(BISECTIONS):
        mid = 0.5 * (inside + outside)
        ll, best = yield mid
        if ll < best - drop:
            outside = mid
        else:
            inside = mid
    return 0.5 * (inside + outside), False


def profile_bounds(loglik: Callable[[float], float], value: float, best: float, step: float, low: float,
                   high: float, drop: float = HALF_CHI2_1_95) -> tuple[list[float], list[bool], list[tuple[float, float]],
                                                                      float]:
    """([lower, upper] ends of the 95% profile interval around ``value``, [lower, upper] open: the profile stayed
    within 1.92 nats up to that end (the domain's bound, or the farthest of MAX_STEPS doubling steps), the
    (v, loglik) points evaluated, the best log-likelihood seen; a failed point is -inf, beyond the interval).
    ``loglik(v)``: the profile at v (with ``many``, ``HeldFits``: the two sides' points side by side); ``best``: its
    maximum so far (the free fit's), raised when a point beats it; ``drop``: the nats below the best that bound the
    interval (1.92; a robust interval's larger, ``robust_drop``)."""
    sides, points, best = walk_in_step(loglik, [bracket_side(value, -1.0, step, low, drop),
                                                bracket_side(value, 1.0, step, high, drop)], best)
    return [e for e, _ in sides], [o for _, o in sides], points, best


def _held_fit(job: tuple[Model, list[Trajectory], str, str, float, EMOptions, bool]) -> tuple[float, Model | None, str]:
    """One held fit (a worker's job, ``HeldFits``): (its log-likelihood, the fit when asked for, else None, "" or why
    the fit failed numerically: then -inf, beyond any interval)."""
    from learners.discrepancy.fitting import fit, train_loglik, with_values

    final, logs, name, pname, v, held_opts, keep = job
    try:
        model = fit(logs, final.with_effect(with_values(final.effect(name), {pname: v})), held_opts)
    except (FloatingPointError, np.linalg.LinAlgError, ValueError) as err:  # counted as beyond the interval
        return -math.inf, None, f"the fit with {pname} held at {v:.3g} failed ({err})"
    return train_loglik(model, logs), (model if keep else None), ""


class HeldFits:
    """v -> the log-likelihood of ``logs`` (``fitting.train_loglik``) under ``final`` refitted with parameter ``pname``
    of effect ``name`` held at v (the rest refitted, warm-started: one start and no alias search, ``fitting.fit``; the
    search's stop rule, ``fitting.held``); a fit that fails numerically is -inf (beyond any interval) and said in
    ``failed``. ``fits``: where given, each fit made is kept in it (v -> (log-likelihood, model)). ``many(values)``
    makes several at once, side by side in ``pool`` (a worker pool, ``aibo_core.workers.process_pool``) where there is
    one: the walks below ask for both sides' next points together. The fits are deterministic, so the pool changes
    when a profile is done, not what it finds."""

    def __init__(self, final: Model, logs: list[Trajectory], name: str, pname: str, opts: EMOptions,
                 failed: list[str], fits: dict[float, tuple[float, Model]] | None = None, pool: Any = None) -> None:
        from learners.discrepancy.fitting import SEARCH_PATIENCE, held

        self.final, self.logs, self.name, self.pname = final, logs, name, pname
        self.held_opts = held(replace(opts.comparable(), patience=SEARCH_PATIENCE), name)
        self.failed, self.fits, self.pool = failed, fits, pool

    def many(self, values: list[float]) -> list[float]:
        """The log-likelihoods of the fits held at ``values``, in order."""
        keep = self.fits is not None
        jobs = [(self.final, self.logs, self.name, self.pname, float(v), self.held_opts, keep) for v in values]
        out = []
        for v, (ll, model, why) in zip(values, pool_map(self.pool if len(jobs) > 1 else None, _held_fit, jobs)):
            if why:
                self.failed.append(why)
            elif keep:
                self.fits[float(v)] = (ll, model)
            out.append(ll)
        return out

    def __call__(self, v: float) -> float:
        return self.many([v])[0]


def held_loglik(final: Model, logs: list[Trajectory], name: str, pname: str, opts: EMOptions,
                failed: list[str], fits: dict[float, tuple[float, Model]] | None = None, pool: Any = None) -> HeldFits:
    """The held fits of ``pname`` of effect ``name`` about ``final`` (``HeldFits``)."""
    return HeldFits(final, logs, name, pname, opts, failed, fits, pool)


def batched(loglik: Callable[[float], float]) -> Callable[[list[float]], list[float]]:
    """``loglik``'s ``many`` (``HeldFits``: several points side by side), else one point after the other."""
    return getattr(loglik, "many", None) or (lambda values: [loglik(v) for v in values])


class Scaled:
    """``loglik`` of a lattice index k at the value k x ``resolution`` (``step_walk`` of a lag in frames), its
    ``many`` kept (``batched``)."""

    def __init__(self, loglik: Callable[[float], float], resolution: float) -> None:
        self.loglik, self.resolution = loglik, resolution

    def many(self, ks: list[int]) -> list[float]:
        return batched(self.loglik)([k * self.resolution for k in ks])

    def __call__(self, k: int) -> float:
        return self.many([k])[0]


def walk_in_step(loglik: Callable[[float], float], walks: list[Generator[float, tuple[float, float], Any]],
                 best: float) -> tuple[list[Any], list[tuple[float, float]], float]:
    """Run ``walks`` side by side: each is a generator that yields the next point it needs and is sent (that point's
    log-likelihood, the best log-likelihood so far). Each round evaluates every unfinished walk's next point together
    (``batched``: in a worker pool where ``loglik`` has one) and raises ``best`` by them before any walk reads it.
    Returns (each walk's return value, the (v, loglik) points in the order evaluated, the best)."""
    points: list[tuple[float, float]] = []
    results: list[Any] = [None] * len(walks)
    pending: dict[int, float] = {}
    for i, w in enumerate(walks):
        try:
            pending[i] = next(w)
        except StopIteration as stop:  # nothing to evaluate (at the domain's end already)
            results[i] = stop.value
    many = batched(loglik)
    while pending:
        ids = list(pending)
        values = many([pending[i] for i in ids])
        points += [(pending[i], ll) for i, ll in zip(ids, values)]
        best = max([best, *values])
        for i, ll in zip(ids, values):
            try:
                pending[i] = walks[i].send((ll, best))
            except StopIteration as stop:
                results[i] = stop.value
                del pending[i]
    return results, points, best


def profile_interval(final: Model, logs: list[Trajectory], name: str, se: float | None, opts: EMOptions,
                     drop: float = HALF_CHI2_1_95, pool: Any = None) -> dict:
    """The 95% profile-likelihood interval of effect ``name``'s one scalar parameter in the diagnosed model
    ``final`` (fitted on ``logs``; ``opts``: its fit's options): {"interval_95", "open", "method", "points", "note",
    "beaten_by_nats"} (module docstring, ``profile_bounds``; ``drop``: its nats, ``robust_drop``; ``pool``: where the
    held fits run, ``HeldFits``)."""
    from learners.discrepancy.fitting import train_loglik

    pname = profiled_parameter(name)
    if pname is None:
        raise ValueError(f"{name}: no single scalar parameter to profile")
    param = EFFECT_MODELS[name].PARAMS[pname]
    value = float(np.asarray(final.effect(name).values()[pname]))
    scale = float(np.max(np.atleast_1d(param.scale)))
    step = se if se is not None and math.isfinite(se) and se > 0 else 0.1 * max(abs(value), scale)
    failed: list[str] = []
    loglik = held_loglik(final, logs, name, pname, opts, failed, pool=pool)
    free = train_loglik(final, logs)
    ends, open_ends, points, best = profile_bounds(loglik, value, free, step, param.low, param.high, drop)
    notes = [f"the profile stays within {drop:.2f} nats of its best up to "
             f"{'the domain bound ' if e in (param.low, param.high) else ''}{e:.3g}" for e, o in zip(ends, open_ends) if o]
    notes += failed
    if best > free + BEATEN_NATS:  # the fit held elsewhere is more likely: the diagnosed fit is not the maximum
        notes.append(f"a fit with {pname} held at another value is {best - free:.1f} nats more likely than the diagnosed "
                     f"model: {NOT_THE_MAXIMUM}")
    method = "profile likelihood, whole logs" + ("" if drop == HALF_CHI2_1_95 else
                                                 f", robust (the drop {drop:.2f} nats: 1.92 x (robust / Fisher SE)^2)")
    return {"interval_95": ends, "open": open_ends, "method": method,
            "points": [[float(v), float(ll)] for v, ll in sorted(points)], "note": "; ".join(notes),
            "beaten_by_nats": max(0.0, float(best - free))}


def conditional_interval(final: Model, logs: list[Trajectory], name: str, se: float | None) -> dict:
    """The 95% conditional likelihood interval of effect ``name``'s one scalar parameter (``conditional_parameter``) in
    the diagnosed model ``final`` on ``logs``: everything else held at ``final``'s values, the log-likelihood (the
    E-step's, mixtures included) walked and bisected as ``profile_bounds`` does. Same keys as ``profile_interval``."""
    from learners.discrepancy.fitting import train_loglik, with_values

    pname = conditional_parameter(name)
    if pname is None:
        raise ValueError(f"{name}: no single scalar parameter with batch state")
    param = EFFECT_MODELS[name].PARAMS[pname]
    effect = final.effect(name)
    value = float(np.asarray(effect.values()[pname]))
    scale = float(np.max(np.atleast_1d(param.scale)))
    step = se if se is not None and math.isfinite(se) and se > 0 else 0.1 * max(abs(value), scale)

    def loglik(v: float) -> float:
        try:
            return train_loglik(final.with_effect(with_values(effect, {pname: v})), logs)
        except (FloatingPointError, np.linalg.LinAlgError, ValueError):  # beyond the interval
            return -math.inf

    ends, open_ends, points, _ = profile_bounds(loglik, value, train_loglik(final, logs), step, param.low, param.high)
    notes = [f"the likelihood stays within {HALF_CHI2_1_95:.2f} nats of its best up to "
             f"{'the domain bound ' if e in (param.low, param.high) else ''}{e:.3g}" for e, o in zip(ends, open_ends) if o]
    return {"interval_95": ends, "open": open_ends,
            "method": "conditional likelihood, whole logs (the other parameters held at the final fit's values)",
            "points": [[float(v), float(ll)] for v, ll in sorted(points)], "note": "; ".join(notes)}


def lattice_side(start: int, side: int, bound: int) -> Generator[int, tuple[float, float], bool]:
    """One side of ``step_walk`` as a walk (``walk_in_step``): from ``start`` one step at a time towards ``bound``
    until a point drops more than 1.92 nats below the best or the lattice ends. Returns whether it reached ``bound``
    still inside."""
    k, inside = start, start
    while (k + side - bound) * side <= 0:
        k += side
        ll, best = yield k
        if ll < best - HALF_CHI2_1_95:
            break
        inside = k
    return inside == bound


def step_walk(loglik: Callable[[int], float], start: int, best: float, low: int,
              high: int) -> tuple[list[int], list[bool], list[tuple[int, float]], float]:
    """The profile of a parameter that takes values on a lattice (index k: a lag of k frames), walked from ``start``
    one step at a time on each side until it drops more than 1.92 nats below ``best`` (raised when a point beats it)
    or the lattice ends (``low``, ``high``); both sides side by side (``walk_in_step``). Returns ([lowest, highest]
    index within 1.92 nats of the best, [lower, upper] open: the walk reached that end still inside, the (index,
    loglik) points with ``start``'s (``best``, the free fit's) among them, the best log-likelihood seen). Every index
    between the ends is taken to be inside (the profile of a lag is unimodal near its best)."""
    points: list[tuple[int, float]] = [(start, best)]
    open_ends, walked, best = walk_in_step(loglik, [lattice_side(start, -1, low), lattice_side(start, 1, high)], best)
    points += walked
    # a point inside may fall out once a later one raised the best: the ends are those still within 1.92 nats
    kept = [k for k, ll in points if ll >= best - HALF_CHI2_1_95]
    return [min(kept), max(kept)], open_ends, sorted(points), best


def beaten_by(points: list[tuple[float, float]], free: float) -> float:
    """Nats by which the most likely held fit of ``points`` ((value, loglik)) beats the final fit's ``free`` (0: none
    does): an interval entry's ``beaten_by_nats``; above 1.92 the value stated is outside its own profile interval."""
    return max([0.0] + [float(ll - free) for _, ll in points if math.isfinite(ll)])


def beaten(points: list[tuple[float, float]], free: float, pname: str, notes: list[str]) -> float | None:
    """The value of the most likely held fit of ``points`` ((value, loglik)) when it beats the final fit's ``free`` by
    ``BEATEN_NATS`` (said in ``notes``, in place), else None."""
    value, best = max(points, key=lambda p: p[1])
    if best <= free + BEATEN_NATS:
        return None
    notes.append(f"a fit with {pname} held at {value:.3g} is {best - free:.1f} nats more likely than the diagnosed "
                 f"model: {NOT_THE_MAXIMUM}")
    return float(value)


def lattice_interval(final: Model, logs: list[Trajectory], name: str, pname: str, resolution: float,
                     opts: EMOptions, pool: Any = None) -> dict:
    """The 95% profile-likelihood interval of grid parameter ``pname`` of effect ``name`` in the diagnosed model
    ``final`` (fitted on ``logs``; ``opts``: its fit's options) at the step ``resolution`` below which the parameter
    does not change the model (``EffectModel.grid_resolution``: a lag of discrete commands acts in whole frames):
    each value k x resolution fitted with the effect held there (the rest refitted, warm-started from ``final``),
    walked out from the estimate (``step_walk``). A value k x resolution stands for every value in
    ((k - 1) resolution, k x resolution], so the interval is [(k_lo - 1) resolution, k_hi resolution] (0 at least).
    Keys: "interval_95", "open", "method", "points", "note" (as ``profile_interval``'s) and "better": the value whose
    held fit is more likely than ``final`` by ``BEATEN_NATS`` (None when none is)."""
    from learners.discrepancy.fitting import train_loglik

    param = EFFECT_MODELS[name].PARAMS[pname]
    value = float(np.asarray(final.effect(name).values()[pname]))
    failed: list[str] = []
    held_ll = held_loglik(final, logs, name, pname, opts, failed, pool=pool)
    free = train_loglik(final, logs)
    top = max(EFFECT_MODELS[name].GRID[pname])
    high = math.floor(min(param.high, top) / resolution + 1e-9)
    k0 = round(value / resolution)
    frames = Scaled(held_ll, resolution)
    (k_lo, k_hi), open_ends, points, _ = step_walk(frames, k0, free, 0, high)
    # the value stated stays inside its interval even where a held fit beat it (said in the note): on a `paper-sim`
    # log of a 0.15 s lag the final fit made again from the better frame (4) ended at 5 frames, 200 nats below it
    k_lo, k_hi = min(k_lo, k0), max(k_hi, k0)
    notes = [f"the profile stays within {HALF_CHI2_1_95:.2f} nats of its best up to the grid's end {top:g}"] \
        if open_ends[1] else []
    notes += failed
    valued = [(k * resolution, ll) for k, ll in points]  # (value, loglik), in order
    better = beaten(valued, free, pname, notes)
    return {"interval_95": [max(k_lo - 1, 0) * resolution, k_hi * resolution], "open": [False, open_ends[1]],
            "better": better, "beaten_by_nats": beaten_by(valued, free),
            "method": (f"profile likelihood at the model's own step ({resolution:.4g}: a value k steps stands for every "
                       "value in ((k - 1) steps, k steps]), whole logs"),
            "points": [[float(v), float(ll)] for v, ll in valued], "note": "; ".join(notes)}


def local_step(value: float, step: float, low: float) -> float:
    """The spacing of ``parabola_interval``'s held fits about ``value``: the grid's ``step``, or where half of it
    would cross the domain's ``low`` end, the distance to that end (at least a quarter of the step), so that the
    parabola has points on both sides. Measured: a lag of 0.048 s (an independent generator's log, net lag 0.05 s) had
    points at +0.05 and +0.1 only, and the parabola through them, nearly a line there, gave [0, 0.075] where its
    profile drops 249 nats in 0.05 s; ``aibo learn``'s interval, from points on both sides, [0.045, 0.052]."""
    if value - step / 2.0 >= low:
        return step
    return max(value - low, step / 4.0)


def parabola_interval(final: Model, logs: list[Trajectory], name: str, pname: str, step: float,
                      opts: EMOptions, pool: Any = None) -> dict:
    """The 95% profile-likelihood interval of grid parameter ``pname`` of effect ``name`` where it acts continuously
    (a lag of continuous commands): the fits with it held at the final value +- ``step`` / 2 and +- ``step`` (the
    search's grid step; the rest refitted, warm-started from ``final``) and the final fit itself, a parabola through
    them and the interval where it drops 1.92 nats below its top (``learners.em.lag.refine``, ``aibo learn``'s own
    lag interval: on MRCLAM logs with the commands shifted by known offsets it held the shift in 30 of 35 cases),
    widened to hold the value; near the domain's end the points closer (``local_step``). Keys as
    ``lattice_interval``'s."""
    from learners.discrepancy.fitting import train_loglik
    from learners.em.lag import holding, refine

    param = EFFECT_MODELS[name].PARAMS[pname]
    value = float(np.asarray(final.effect(name).values()[pname]))
    failed: list[str] = []
    held_ll = held_loglik(final, logs, name, pname, opts, failed, pool=pool)
    free = train_loglik(final, logs)
    step = local_step(value, step, param.low)
    below = {max(v, param.low) for v in (value - step, value - step / 2)} - {value}  # at most the domain's end
    values = sorted(below) + [value + step / 2, value + step]
    points = [(value, free)] + list(zip(values, batched(held_ll)(values)))
    finite = [(v, ll) for v, ll in points if math.isfinite(ll)]
    _, parabola, note = refine(sorted(finite), value, step)
    interval, note = holding(parabola, value, note)
    notes = ([note] if note else []) + failed
    better = beaten(points, free, pname, notes)
    return {"interval_95": interval, "open": [False, False], "better": better,
            "beaten_by_nats": beaten_by(points, free),
            "method": (f"profile likelihood, whole logs: a parabola through the fits with {pname} held at the value and "
                       f"+-{step / 2:g}, +-{step:g} (the rest refitted)"),
            "points": [[float(v), float(ll)] for v, ll in sorted(points)], "note": "; ".join(notes)}


def refine_grid_intervals(effects: list[dict], final: Model, logs: list[Trajectory], opts: EMOptions,
                          pool: Any = None) -> tuple[list[str], dict[str, dict[str, float]]]:
    """For each named effect of ``report.json["effects"]`` with a grid parameter: its interval (the search's grid one,
    kept as ``grid_interval_95``) replaced, in place, by the whole logs' profile: at the step the logs resolve where
    that is finer than the grid (``EffectModel.grid_resolution``: a lag of discrete commands, in frames;
    ``lattice_interval``; ``grid_step`` that step), else, where it acts continuously, a parabola through held fits
    about the value (``parabola_interval``; no ``grid_step``). ``profile``: the points. Returns the names refined and, per
    effect, the parameters whose profile found a more likely value than ``final``'s (that value)."""
    from learners.arrays.batch import make_batch

    done: list[str] = []
    better: dict[str, dict[str, float]] = {}
    batch = None
    for e in effects:
        effect = final.effect(e["name"])
        for pname in effect.GRID:
            entry = e["intervals"].get(pname)
            batch = batch if batch is not None else make_batch(logs)
            if entry is None or entry.get("interval_95") is None:
                continue
            resolution = effect.grid_resolution(pname, batch)
            if resolution is not None:
                p = lattice_interval(final, logs, e["name"], pname, resolution, opts, pool)
                entry["grid_step"] = float(resolution)
            else:
                p = parabola_interval(final, logs, e["name"], pname, float(entry.get("grid_step", 0.1)), opts, pool)
                entry.pop("grid_step", None)
            entry.update(grid_interval_95=entry["interval_95"], interval_95=p["interval_95"], open=p["open"],
                         method=p["method"], profile=p["points"], note=p["note"], beaten_by_nats=p["beaten_by_nats"])
            done.append(e["name"])
            if p["better"] is not None:
                better.setdefault(e["name"], {})[pname] = p["better"]
    return done, better


def climb(loglik: Callable[[float], float], start: float, step: float, best: float, bound: float) -> tuple[float, float]:
    """(value, loglik) of the most likely point of a walk from ``start`` (whose ``loglik`` is ``best``) in steps of
    ``step`` (signed) while each point beats the last, at most MAX_STEPS points, the domain's ``bound`` the last
    (a failed point is -inf: the walk stops)."""
    value = start
    for _ in range(MAX_STEPS):
        v = value + step
        if (v - bound) * step >= 0:
            v = bound
        out = loglik(v)
        if out <= best:
            break
        value, best = v, out
        if v == bound:
            break
    return value, best


def robust_drop(entry: dict) -> float:
    """The nats below the best that bound a 95% interval with the robust standard error's width: 1.92 x (robust SE /
    Fisher SE)^2 (a Wald entry's ``se`` and ``se_fisher``; 1.92 where they are one). Under a quadratic profile of the
    Fisher curvature it puts the ends at the robust Wald ones, so that a profile interval keeps the sandwich's
    allowance for a misspecified model (the adjusted likelihood-ratio interval, e.g. Royall & Tsou 2003)."""
    se, fisher = entry.get("se"), entry.get("se_fisher")
    if se is None or fisher is None or not fisher > 0:
        return HALF_CHI2_1_95
    return HALF_CHI2_1_95 * max(float(se) / float(fisher), 1.0) ** 2


def wald_ends(final: Model, logs: list[Trajectory], name: str, entry: dict, opts: EMOptions, pool: Any = None) -> dict:
    """The check of a Wald interval ``entry`` (``effect_sizes.effect_intervals``) of effect ``name``'s one scalar
    parameter (``profiled_parameter``) in the diagnosed model ``final``: fits with the parameter held at the
    interval's two ends, the rest refitted (``held_loglik``). Under the quadratic log-likelihood Wald assumes, each is
    ``robust_drop`` below the final fit (1.92 nats for Fisher errors). Returns {"points": [[v, loglik], ...] (the
    ends; a beaten side's climb after them), "free": the final fit's, "inside": whether an end is less than that
    below the best (the profile is flatter on that side than the interval says), "better": where an end's fit beats
    the final fit by ``BEATEN_NATS`` (the final fit stopped short of the maximum: a ridge EM creeps along), the most
    likely value of the walk on from that end in steps of the interval's half-width (``climb``), else None, "held":
    that value's (log-likelihood, held fit)}."""
    from learners.discrepancy.fitting import train_loglik

    pname = profiled_parameter(name)
    param = EFFECT_MODELS[name].PARAMS[pname]
    value = float(np.asarray(entry["value"]))
    failed: list[str] = []
    fits: dict[float, tuple[float, Model]] = {}
    loglik = held_loglik(final, logs, name, pname, opts, failed, fits, pool)
    free = train_loglik(final, logs)
    ends = [e for e in (min(max(float(e), param.low), param.high) for e in entry["interval_95"]) if e != value]
    points = list(zip(ends, batched(loglik)(ends)))  # side by side in the pool
    better = None
    top_v, top = max(points, key=lambda p: p[1], default=(value, free))
    if top > free + BEATEN_NATS:
        half = abs(top_v - value)
        bound = param.high if top_v > value else param.low
        walked: list[tuple[float, float]] = []

        def logged(v: float) -> float:
            walked.append((v, loglik(v)))
            return walked[-1][1]

        better, _ = climb(logged, top_v, half if top_v > value else -half, top, bound)
        points += walked
    best = max([free] + [ll for _, ll in points])
    inside = any(ll >= best - robust_drop(entry) for _, ll in points[:2])
    return {"points": [[float(v), float(ll)] for v, ll in points], "free": float(free), "inside": bool(inside),
            "better": better, "held": None if better is None else fits[better], "failed": failed}


def check_wald_intervals(effects: list[dict], final: Model, logs: list[Trajectory], opts: EMOptions,
                         skip: list[str], pool: Any = None) -> tuple[list[str], Model | None]:
    """For each named effect of ``report.json["effects"]`` not in ``skip`` (profiled already) whose one scalar
    parameter (``profiled_parameter``) has a Wald interval: ``wald_ends``, kept in the entry as ``wald_check``
    ({"points", "free"}). Where an end's fit is within ``robust_drop`` of the best, the interval is replaced, in
    place, by the profile-likelihood one to that drop (``profile_interval``; the Wald one kept as
    ``wald_interval_95``). Returns the names
    profiled and, where held fits beat ``final`` (the climb's best, ``wald_ends``), the most likely of them: the
    final fit is then made again from it (``final.diagnosed``), whose likelihood it starts at.

    Why: a final fit can stop on a ridge. On a simulated 5-minute `aibo` log of ``distance_dependent_noise`` at
    exponent 0.5 (seed 8022, scripts/calibration.py's log 22) the final fit ended at 0.27 (SE 0.046) while the fit
    with the exponent held at 0.5 was 46 nats more likely; that one log made the exponents spread twice their
    standard error over the calibration logs. Made again from the held fit the climb found (0.54), the final fit
    ends at 0.45, 8 nats above that held fit, with a profile interval [0.36, 0.53] (from the search's model with
    0.54 it crept back to 0.31; docs/results.md, "Calibration")."""
    done: list[str] = []
    better: tuple[float, Model] | None = None
    for e in effects:
        pname = profiled_parameter(e["name"])
        if e["name"] in skip or pname is None:
            continue
        entry = e["intervals"].get(pname)
        if entry is None or entry.get("interval_95") is None or wants_profile(entry):
            continue
        check = wald_ends(final, logs, e["name"], entry, opts, pool)
        entry["wald_check"] = {"points": check["points"], "free": check["free"]}
        if check["better"] is not None:
            better = max(better or check["held"], check["held"], key=lambda h: h[0])
            entry["beaten_by_nats"] = beaten_by(check["points"], check["free"])
            entry["note"] = "; ".join(check["failed"] + [
                f"a fit with {pname} held at {check['better']:.3g} is more likely than the diagnosed model by "
                f"{entry['beaten_by_nats']:.1f} nats: {NOT_THE_MAXIMUM}"])
        elif check["inside"]:
            p = profile_interval(final, logs, e["name"], entry.get("se"), opts, robust_drop(entry), pool)
            entry.update(wald_interval_95=entry["interval_95"], interval_95=p["interval_95"], open=p["open"],
                         method=p["method"], profile=p["points"], note=p["note"], beaten_by_nats=p["beaten_by_nats"])
            done.append(e["name"])
    return done, None if better is None else better[1]


def profile_where_wald_fails(effects: list[dict], final: Model, logs: list[Trajectory], opts: EMOptions,
                             pool: Any = None) -> list[str]:
    """For each named effect of ``report.json["effects"]`` (each with its ``intervals``) whose one scalar parameter's
    Wald interval is clipped at its domain or missing (``wants_profile``): its interval replaced, in place, by the
    profile-likelihood one (for a parameter with batch state the conditional likelihood one, ``conditional_interval``;
    the Wald one kept as ``wald_interval_95``; ``profile``: the points, ``note``). Returns the names profiled."""
    done = []
    for e in effects:
        pname = profiled_parameter(e["name"]) or conditional_parameter(e["name"])
        if pname is None or not wants_profile(e["intervals"][pname]):
            continue
        entry = e["intervals"][pname]
        p = (profile_interval(final, logs, e["name"], entry["se"], opts, pool=pool) if profiled_parameter(e["name"])
             else conditional_interval(final, logs, e["name"], entry["se"]))
        entry.update(wald_interval_95=entry["interval_95"], interval_95=p["interval_95"], open=p["open"],
                     method=p["method"], profile=p["points"], note=p["note"])
        if "beaten_by_nats" in p:  # a conditional interval's points hold the rest at the final fit: none beats it
            entry["beaten_by_nats"] = p["beaten_by_nats"]
        done.append(e["name"])
    return done
