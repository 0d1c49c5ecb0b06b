"""Name the missing effect: stepwise selection over the catalogue, each step a round of declared checks.

A round fits every remaining candidate warm-started from the current model on the training half (an effect with a
grid parameter, e.g. a lag, by profile likelihood over its grid), scores it on the held-out half and runs its checks
(``learners.discrepancy.checks``: the likelihood-ratio test against the refitted null, then the checks that may refuse
it). The significant candidate with the best held-out gain is named and becomes the current model; the search
repeats until nothing is significant (at most ``MAX_ROUNDS``, ``aibo diagnose --rounds``; a candidate still significant
in the last round is reported as left by that limit). Two rules act on the round, not on one candidate:

- an escape: a candidate's check fitted a base model WITHOUT the effect that beats the round's null by
  ``ESCAPE_NATS`` (EM from the paper's start had stopped at a poorer optimum of the base): it becomes the current
  model and the round is repeated from it (at most ``MAX_ESCAPES`` times), the escaped-from candidate fitted from its
  own fit of the round too;
- the backward check (:func:`prune`, stepwise selection's elimination step): once two or more effects are named,
  each must still earn its place given the others (the robust likelihood-ratio test that named it, the level shared
  by the named effects); the weakest that fails is dropped and the check repeats;
- after each naming, an effect the new one made implausible (:func:`drop_implausible`) is dropped at once, so that
  the rounds left try what it had stood in for.

Last, the "none of the above" probes (``learners.model.probes``: effects outside the catalogue) are fitted on the
final model and tested as candidates are. The evidence behind each rule is in docs/results.md ("The search's
checks").
"""

from __future__ import annotations

import time
from concurrent.futures import FIRST_COMPLETED, Future, wait
from contextlib import nullcontext
from dataclasses import dataclass, field, replace
from typing import Any, Callable, NamedTuple

import numpy as np

from aibo_core.trajectory import Trajectory
from aibo_core.workers import pool_map, process_pool
from learners.arrays.batch import make_batch
from learners.base import LearnResult
from learners.em.bearing_sign import sign_check, sign_warnings
from learners.em.estep import e_step
from learners.em.learner import EMLearner
from learners.em.map_check import exchanges, judged, repair_warning, tried_exchanges
from learners.em.options import DEFAULT_GATE, EMOptions
from learners.model.effects import EFFECT_MODELS
from learners.model.model import Model
from learners.model.probes import PROBES

from .candidate import Candidate, Verdict
from .checks import CANDIDATE_CHECKS, LAST_ROUND_CHECKS, PROBE_CHECKS, MotionSide, RobustLikelihoodRatio, run_checks, tested
from .fitting import SEARCH_PATIENCE, SearchContext, fit, fit_from_paper_start, learned, lr_test, train_loglik
from .grid import GridWalk, candidate_start, grid_point, profiled
from .split import training_log

#: Rounds at most (``aibo diagnose --rounds``). Measured on the five MRCLAM robots' whole logs (2026-11-27): with the
#: limit at 10 instead, robots 1, 3 and 4 name the same; robot 2 adds distance_dependent_noise in a 4th round (forward
#: error against Vicon 6.1 -> 6.4 mm/s, 8 disagreements of the calibrated check either way) and robot 5
#: landmark_bias, dropped in the final fit (gap 1.78 -> 2.07, disagreements 8 -> 11): no robot better with more
#: (docs/results.md, "The limit of rounds").
MAX_ROUNDS = 3
#: A candidate's base refit (``checks.GivenItsOwnBase``) this many nats above the round's null replaces the current
#: model and the round is repeated from it, at most ``MAX_ESCAPES`` times per search.
ESCAPE_NATS = 2.0
MAX_ESCAPES = 2


#: ``EffectModel.NEEDS`` in the words of "not tried: the log(s) hold no ..." (the field's own name where not listed)
NEEDS_WORDS = {"controls": "continuous commands (controls)", "head_pan": "head_pan"}


def applicable(name: str, logs: list[Trajectory]) -> bool:
    """Whether the logs hold what the effect needs (e.g. a head pan)."""
    return all(all(getattr(tr, need) is not None for tr in logs) for need in EFFECT_MODELS[name].NEEDS)


def fit_candidate(name: str, ctx: SearchContext, previous: Model | None = None) -> Candidate:
    """The current model extended with effect ``name`` and fitted (warm-started: the effect's ``start`` and
    ``warm_start``), with its likelihood-ratio verdict. A grid effect is profiled over its grid
    (``learners.discrepancy.grid``). ``previous``: a model holding the effect to fit from as well (not for a grid
    effect), the more likely fit kept: the candidate's own fit of the round that an escape repeats."""
    if EFFECT_MODELS[name].GRID:
        return profiled(name, ctx)
    start = candidate_start(name, ctx)
    model = ctx.fit(start)
    ll = ctx.loglik(model)
    if previous is not None:
        again = ctx.fit(previous)
        ll_again = ctx.loglik(again)
        model, ll = (again, ll_again) if ll_again > ll else (model, ll)
    if model.effect(name).implausible() and model.effect(name).ridge_possible():
        model, ll = staged(name, start, model, ll, ctx)
    c = tested(name, model, ll, ctx)
    c.start = start
    return c


def staged(name: str, start: Model, model: Model, ll: float, ctx: SearchContext) -> tuple[Model, float]:
    """A candidate whose fit ended implausible (``EffectModel.implausible``) fitted again in two stages: the rest of
    the model first, with the effect frozen at its warm start, then everything from there; the more likely of the two
    fits (and its training log-likelihood). EM can move an effect's parameters before the base has adapted to it and
    climb a ridge (docs/results.md, "Staged fits")."""
    frozen = ctx.fit(start, replace(ctx.opts, frozen=ctx.opts.frozen + (name,)))
    again = ctx.fit(frozen)
    ll_again = ctx.loglik(again)
    return (again, ll_again) if ll_again > ll else (model, ll)


def try_candidate(name: str, ctx: SearchContext, previous: Model | None = None) -> Candidate:
    """Candidate ``name`` fitted (:func:`fit_candidate`) and put through ``checks.CANDIDATE_CHECKS``."""
    t0 = time.perf_counter()
    c = run_checks(CANDIDATE_CHECKS, ctx, fit_candidate(name, ctx, previous))
    c.seconds = time.perf_counter() - t0
    return c


def try_probe(name: str, ctx: SearchContext) -> Candidate:
    """The "none of the above" check of probe ``name`` (``learners.model.probes``) on the search's final model
    ``ctx.current``: fitted warm-started with its covariates read off that model's smoothed path, tested as a
    candidate is, and put through ``checks.PROBE_CHECKS``."""
    t0 = time.perf_counter()
    start = ctx.current.with_effect(PROBES[name].around(ctx.posterior, ctx.batch))
    model = ctx.fit(start)
    c = tested(name, model, ctx.loglik(model), ctx)
    c.start = start
    run_checks(PROBE_CHECKS, ctx, c)
    c.seconds = time.perf_counter() - t0
    return c


@dataclass(frozen=True)
class Trial:
    """One job of the worker pool: candidate (or probe, ``probe=True``) ``name`` in the round of ``ctx``."""

    name: str
    ctx: SearchContext
    previous: Model | None = None
    probe: bool = False


def run_trial(t: Trial) -> Candidate:
    """:func:`try_candidate` or :func:`try_probe`; a fit that fails numerically is reported (its verdict "fit" not
    passed) instead of ending the search."""
    try:
        return try_probe(t.name, t.ctx) if t.probe else try_candidate(t.name, t.ctx, t.previous)
    except (FloatingPointError, np.linalg.LinAlgError, ValueError) as err:
        return _failed(t.name, err)


def _failed(name: str, err: Exception) -> Candidate:
    """The candidate of a fit that failed numerically: its verdict "fit" not passed, with why."""
    return Candidate(name, {}, 0.0, 0.0, 0, 1.0, checks=[Verdict("fit", False, note=f"fit failed: {err}")])


def _point_job(args: tuple[str, SearchContext, Model, float]) -> tuple[Model, float] | Exception:
    try:
        return grid_point(args)
    except (FloatingPointError, np.linalg.LinAlgError, ValueError) as err:
        return err


def _walked_job(args: tuple[GridWalk, float]) -> Candidate:
    """A settled walk's candidate (``GridWalk.candidate``: its held-out scores) put through the candidate checks;
    ``seconds``: its points' wall time so far."""
    walk, seconds = args
    t0 = time.perf_counter()
    try:
        c = run_checks(CANDIDATE_CHECKS, walk.ctx, walk.candidate())
    except (FloatingPointError, np.linalg.LinAlgError, ValueError) as err:
        return _failed(walk.name, err)
    c.seconds = seconds + time.perf_counter() - t0
    return c


def run_round(trials: list[Trial], pool: Any, jobs: int = 1) -> list[Candidate]:
    """Every trial of a round (``run_trial``), in order. On a worker pool of ``jobs`` workers, a grid candidate's
    profile points are jobs of their own, submitted first and kept ``jobs`` ahead of its walk, and its checks one more
    job once the walk is settled (``learners.discrepancy.grid``): the same fits and decisions as one process walking
    the grid, without the round waiting for one worker to walk it alone."""
    walks: dict[int, GridWalk] = {}
    out: dict[int, Candidate] = {}
    if pool is not None:
        for i, t in enumerate(trials):
            if not t.probe and EFFECT_MODELS[t.name].GRID:
                try:
                    walks[i] = GridWalk(t.name, t.ctx, candidate_start(t.name, t.ctx))
                except (FloatingPointError, np.linalg.LinAlgError, ValueError) as err:
                    out[i] = _failed(t.name, err)
    if not walks:
        return [out[i] if i in out else c for i, c in enumerate(pool_map(pool, run_trial, trials))]
    pending: dict[Future, tuple[str, int, int]] = {}  # future -> (kind, trial, grid index)
    settled: set[int] = set()  # walks whose candidate is made (late points are dropped)
    began = time.perf_counter()

    def ahead(i: int) -> None:
        w = walks[i]
        while sum(1 for kind, j, _ in pending.values() if kind == "point" and j == i) < jobs:
            k = w.next_value()
            if k is None:
                return
            pending[pool.submit(_point_job, (w.name, w.ctx, w.start, w.grid[k]))] = ("point", i, k)

    for i in walks:
        ahead(i)
    pending.update({pool.submit(run_trial, t): ("trial", i, -1) for i, t in enumerate(trials)
                    if i not in walks and i not in out})
    while pending:
        done, _ = wait(pending, return_when=FIRST_COMPLETED)
        for f in done:
            kind, i, k = pending.pop(f)
            if f.cancelled() or i in settled and kind == "point":
                continue
            if kind != "point":
                out[i] = f.result()
                continue
            w, point = walks[i], f.result()
            if isinstance(point, Exception):
                out[i] = _failed(w.name, point)
                settled.add(i)
                continue
            w.record(k, point)
            if not w.done():
                ahead(i)
                continue
            settled.add(i)
            for g in [g for g, (kd, j, _) in pending.items() if kd == "point" and j == i]:
                g.cancel()  # past the walk's stop: not needed (one already running finishes, unused)
            pending[pool.submit(_walked_job, (w, time.perf_counter() - began))] = ("checks", i, -1)
    return [out[i] for i in range(len(trials))]


def _last_round_job(args: tuple[SearchContext, Candidate]) -> list[Verdict]:
    ctx, c = args
    return [check.run(ctx, c) for check in LAST_ROUND_CHECKS if check.applies(ctx, c)]


def last_round_checks(tried: list[Candidate], ctx: SearchContext, pool: Any) -> None:
    """``checks.LAST_ROUND_CHECKS`` (the frozen probe) on the last round's candidates: they change no decision, so
    the earlier rounds, whose candidates are tried again, skip them (on MRCLAM robot 3 with bias states these fits
    cost 2-4 s each, four to six per round)."""
    todo = [c for c in tried if any(check.applies(ctx, c) for check in LAST_ROUND_CHECKS)]
    for c, verdicts in zip(todo, pool_map(pool, _last_round_job, [(ctx, c) for c in todo])):
        c.checks += verdicts


def drop_outliers(model: Model, logs: list[Trajectory]) -> tuple[list[Trajectory], int]:
    """The logs without the sightings ``model`` gates out as outliers (Mahalanobis^2 > the fit's gate),
    so that every candidate is fitted and scored on the same sightings (likelihoods comparable)."""
    bad = outliers(model, logs)
    return without(logs, bad), int(bad.sum())


def outliers(model: Model, logs: list[Trajectory]) -> np.ndarray:
    """(S,) bool over the logs' sightings in order: those ``model`` gates out (Mahalanobis^2 > the fit's gate)."""
    return np.asarray(e_step(model, make_batch(logs), "compiled", DEFAULT_GATE).mahal2 > DEFAULT_GATE)


def without(logs: list[Trajectory], bad: np.ndarray) -> list[Trajectory]:
    """``logs`` without the sightings flagged in ``bad`` ((S,) bool over the logs' sightings in order)."""
    out, at = [], 0
    for tr in logs:
        out.append(tr.with_sightings(~bad[at:at + tr.n_sightings]))
        at += tr.n_sightings
    return out


#: Above this share of the sightings gated out as outliers, ``aibo learn``'s model of the WHOLE logs judges them too
#: (``base_and_outliers``). On 100 effect-free 5-minute logs (seeds 6000-6049, ``aibo`` and ``paper-sim``,
#: 2026-11-30) the search's base fit set aside none on 52 and 47-2,511 sightings (1-53%) on 17, where the fit of the
#: training half had stopped in a poorer world; on the MRCLAM logs and halves it sets aside 0-11 (at most 0.6%).
OUTLIER_SHARE = 0.01


def base_and_outliers(logs: list[Trajectory], opts: EMOptions, action_model: str | None = None,
                      progress: Callable[[str], None] = print) -> tuple[Model, LearnResult | None, list[Trajectory], int]:
    """(The base model, its refit with spurious sightings or None, the logs without its outliers, how many): the
    search's base fit (:func:`base_fits`, EM from the paper's start on the training halves) and the sightings it gates
    out. A fit of half the sightings can stop in a poorer world and gate out sightings that are none (effect-free
    ``aibo`` log of seed 6045: 1,245 of 4,776, where ``aibo learn`` of the whole log gates none), and every model of the
    search would then be fitted and scored without them. So when more than ``OUTLIER_SHARE`` are gated, ``aibo
    learn``'s model of the whole logs (``fitting.learned``) judges the outliers too: where it gates fewer, the base is
    fitted again on the training halves from it, and of the two bases the one more likely on the training halves'
    sightings that neither gates out is kept, with its outliers. The outliers are a nuisance every compared model
    shares, as the start-pose belief taken from the whole logs (:func:`base_fits`); no compared parameter sees the
    held-out half."""
    base, refit = base_fits(logs, opts, action_model)
    bad = outliers(base, logs)
    if bad.sum() > OUTLIER_SHARE * len(bad) and (better := judged_again(base, bad, logs, opts, action_model)):
        other, other_bad, gain = better
        progress(f"  the base fit gated out {int(bad.sum())} sightings as outliers; fitted from aibo learn's model of "
                 f"the whole log(s) it gates out {int(other_bad.sum())} and is {gain:.1f} nats more likely on the "
                 "sightings neither gates out: kept")
        base, bad = other, other_bad
    return base, refit, without(logs, bad), int(bad.sum())


def judged_again(base: Model, bad: np.ndarray, logs: list[Trajectory], opts: EMOptions,
                 action_model: str | None) -> tuple[Model, np.ndarray, float] | None:
    """(The base fitted on the training halves from ``aibo learn``'s model of the whole ``logs``, the sightings it
    gates out, how much more likely it is than ``base`` on the training halves' sightings neither gates out), or None
    where that model gates out no fewer than ``base`` (``bad``) or is no more likely (``base_and_outliers``)."""
    whole = learned(logs, opts, action_model)
    for e in whole.effects:  # the base's structure: an effect learn added (spurious sightings) stays a candidate
        if base.effect(e.name) is None:
            whole = whole.without_effect(e.name)
    if outliers(whole, logs).sum() >= bad.sum():
        return None
    other = fit([training_log(tr) for tr in logs], whole, opts, action_model)
    other_bad = outliers(other, logs)
    common = [training_log(tr) for tr in without(logs, bad | other_bad)]
    gain = train_loglik(other, common) - train_loglik(base, common)
    return (other, other_bad, gain) if gain > 0 and other_bad.sum() < bad.sum() else None


def _drop_job(args: tuple[str, Model, SearchContext]) -> tuple[Model, float]:
    """Refit ``current`` without effect ``name``: the reduced model and its training log-likelihood."""
    name, current, ctx = args
    reduced = ctx.fit(current.without_effect(name))
    return reduced, ctx.loglik(reduced)


def drop_implausible(named: list[Candidate], current: Model, current_ll: float, ctx: SearchContext,
                     progress: Callable[[str], None]) -> tuple[Model, float]:
    """Drops from ``named`` (in place) each effect whose values the later ones made implausible
    (``EffectModel.implausible``, e.g. a landmark "bias" of 30%, or one that holds for minutes): it was credible when
    named and now stands in for something else. Refits the rest after each drop; returns the model and its training
    log-likelihood."""
    while bad := [c for c in named if current.effect(c.name).implausible()]:
        c = bad[0]
        progress(f"dropped: {c.name} (given the others, {current.effect(c.name).implausible()})")
        named.remove(c)
        current = ctx.fit(current.without_effect(c.name))
        current_ll = ctx.loglik(current)
    return current, current_ll


def prune(named: list[Candidate], current: Model, current_ll: float, ctx: SearchContext, pool: Any,
          progress: Callable[[str], None]) -> tuple[Model, float]:
    """The backward check (module docstring): drops from ``named`` (in place) each effect the others make
    unnecessary, weakest first; returns the model with the effects kept and its training log-likelihood. Before each
    test, an effect whose values the others made implausible (``EffectModel.implausible``, e.g. a landmark "bias" of
    30%) is dropped: it was credible when named and now stands in for something else (checked again after every
    drop, which refits the rest)."""
    while True:
        current, current_ll = drop_implausible(named, current, current_ll, ctx, progress)
        if len(named) < 2:
            return current, current_ll
        refits = pool_map(pool, _drop_job, [(c.name, current, ctx) for c in named])
        heldout = ctx.heldout(current)
        factors = robust_factors(named)
        tests = []
        for c, (reduced, ll) in zip(named, refits):
            raw = max(current_ll - ll, 0.0)
            gain = raw / factors[c.name]
            dof = current.effect(c.name).dof()
            held_gain = heldout - ctx.heldout(reduced)
            p, keep = lr_test(gain, held_gain, dof, len(named))
            scaled = f" (/ {factors[c.name]:.2f}: +{gain:.1f}, robust)" if factors[c.name] > 1.0 else ""
            progress(f"  given the others, {c.name:15s} train +{raw:8.1f} nats{scaled}, held-out {held_gain:+8.1f} "
                     f"nats, p = {p:.2g}{'' if keep else '  NOT NEEDED'}")
            tests.append((keep, p, c, reduced, ll))
        dropped = [t for t in tests if not t[0]]
        if not dropped:
            return current, current_ll
        _, _, c, current, current_ll = max(dropped, key=lambda t: t[1])
        named.remove(c)
        progress(f"dropped: {c.name} (the other named effects explain what it did)")


def robust_factors(named: list[Candidate]) -> dict[str, float]:
    """Per named effect, the factor its training gain is divided by in the backward check: the Fisher information's
    overstatement that its robust likelihood ratio measured when it was named (``checks.RobustLikelihoodRatio``), so
    that an effect is kept given the others by the test that named it; 1 where that check did not run (a grid effect,
    profiled, not estimated; one without parameters). No new sandwich: on MRCLAM robot 1's whole log one of the model
    holding all three effects gave 3.49 and 1.92 for ``landmark_bias`` and ``beacon_height_scale``, and both were kept
    either way."""
    return {c.name: (v.overstatement if (v := c.verdict(RobustLikelihoodRatio.name)) is not None
                     and v.overstatement is not None else 1.0) for c in named}


def with_null(ctx: SearchContext, current: Model, n_tests: int) -> SearchContext:
    """The context of a round extending ``current``: its null is ``current`` refitted from itself with the
    candidates' options, i.e. each candidate's fit with the candidate frozen at its neutral start (the same start,
    the same EM budget, one parameter fewer); docs/results.md, "The null is refitted"."""
    null = ctx.fit(current)
    return replace(ctx, current=current, null_ll=ctx.loglik(null), null_heldout=ctx.heldout(null), n_tests=n_tests)


def base_fit(logs: list[Trajectory], opts: EMOptions, action_model: str | None = None) -> Model:
    """The base model (:func:`base_fits`' first)."""
    return base_fits(logs, opts, action_model)[0]


def base_fits(logs: list[Trajectory], opts: EMOptions, action_model: str | None = None) -> tuple[Model, LearnResult | None]:
    """(The base model, its refit with spurious sightings or None): EM from the paper's start on the logs' training
    halves (``fitting.fit_from_paper_start``: a fit that ends in a wrong world is refitted with ``false_sightings``,
    which the search tries from there too), each log's start-pose belief estimated from the WHOLE log's first
    sightings (``learners.em.start.initial_state_candidates``), not from its training half's: a held-out block can
    hold a log's whole first window. MRCLAM robot 3: every sighting of its first 14 s is in block 1; the training half's first window
    (13.8-16.7 s, three landmarks 0.35 m apart, the robot turning) put the start 5.9 m off, EM kept it (6.5 m off,
    the smoothed pose on the wrong side for 30 s) and the diagnosed model's pose error was 1042 mm (the commands'
    679). The belief is a nuisance shared by every model compared. Among the whole log's candidates it is the one the
    whole log agrees with under the commands' face value, as ``aibo learn`` chooses (``EMLearner.start_params``:
    ``learners.em.starts.chosen_start_pose``)."""
    initial = EMLearner(opts, check_field=False).start_params(logs, None, make_batch(logs), action_model).init
    return fit_from_paper_start([training_log(tr) for tr in logs], opts, action_model, initial)


def _say_round(tried: list[Candidate], progress: Callable[[str], None]) -> None:
    for c in tried:
        progress(f"  {c.name:26s} train +{c.gain_train:8.1f} nats, held-out {c.gain_heldout:+8.1f} nats, "
                 f"p = {c.p_value:.2g}{'  SIGNIFICANT' if c.significant else ''}"
                 f"{'  (not identifiable)' if not c.identifiable else ''}  [{c.seconds:.1f} s]")


class RoundStart(NamedTuple):
    """The state a round of the search started from (``SearchState.starts``)."""

    current: Model
    current_ll: float  # its training log-likelihood (nats)
    named: list[Candidate]
    remaining: list[str]  # the candidates left
    previous: dict[str, Model]  # a second start of the round's candidates (``SearchState.previous``)


@dataclass
class SearchState:
    """Where the search stands: the current model, the candidates left, every round's tries and winner, and the state
    each round started from (``starts``), from which :func:`search_without` runs the search again without an effect."""

    current: Model
    current_ll: float
    remaining: list[str]
    rounds: list[list[Candidate]] = field(default_factory=list)
    named: list[Candidate] = field(default_factory=list)
    winners: list[str] = field(default_factory=list)
    escapes: list[dict[str, Any]] = field(default_factory=list)
    starts: list[RoundStart] = field(default_factory=list)
    #: the next round's second start of a candidate (``fit_candidate``'s ``previous``): an escaped-from candidate's fit
    #: in a repeated round; ``false_sightings``' the base's refit with it where the base ended in a wrong world
    previous: dict[str, Model] = field(default_factory=dict)
    last: SearchContext | None = None  # the last round's context (its null: ``current``'s when nothing was named)


def run_rounds(st: SearchState, ctx: SearchContext, workers: Any, jobs: int, max_rounds: int,
               progress: Callable[[str], None]) -> None:
    """The rounds (module docstring) from ``st`` on, until nothing is significant or ``max_rounds`` rounds are run;
    ``st`` is updated in place. ``workers``: the worker pool (None: this process)."""
    while len(st.rounds) < max_rounds and st.remaining:
        previous = st.previous
        st.starts.append(RoundStart(st.current, st.current_ll, list(st.named), list(st.remaining), dict(previous)))
        st.last = round_ctx = with_null(ctx, st.current, len(st.remaining))
        progress(f"  (null: the current model refitted as the candidates are, train "
                 f"+{round_ctx.null_ll - st.current_ll:.1f} nats)")
        tried = run_round([Trial(n, round_ctx, previous.get(n)) for n in st.remaining], workers, jobs)
        st.rounds.append(tried)
        escape = max(tried, key=lambda c: c.escape_ll)
        escaping = escape.escape_ll > round_ctx.null_ll + ESCAPE_NATS and len(st.escapes) < MAX_ESCAPES
        best = None if escaping else max((c for c in tried if c.significant), key=lambda c: c.gain_heldout,
                                         default=None)
        if not escaping and (best is None or len(st.rounds) == max_rounds or st.remaining == [best.name]):
            last_round_checks(tried, round_ctx, workers)  # the last round: its candidates are reported
        _say_round(tried, progress)
        if escaping:
            # a better base model than the null, found from a candidate's fit: the round is repeated from it
            st.escapes.append({"round": len(st.rounds), "from": escape.name,
                               "nats": escape.escape_ll - round_ctx.null_ll,
                               "candidates": [c.as_dict() for c in st.rounds.pop()]})
            st.starts.pop()
            st.current, st.current_ll = escape.escape, escape.escape_ll
            st.previous = {**previous, escape.name: escape.model}  # a grid candidate's profile ignores it
            progress(f"  the base model refitted from {escape.name}'s fit without it is "
                     f"{escape.escape_ll - round_ctx.null_ll:.1f} nats better than the null: the round is "
                     "repeated from it")
            continue
        st.previous = {}
        if best is None:
            break
        best.checks.append(MotionSide().run(round_ctx, best))
        st.named.append(best)
        st.winners.append(best.name)
        st.current = ctx.fit(best.model)
        st.current_ll = ctx.loglik(st.current)
        st.remaining = [n for n in st.remaining if n != best.name]
        progress(f"named: {best.name} {best.as_dict()['parameters']}"
                 + (f" ({best.checks[-1].note})" if best.checks[-1].note else ""))
        # an effect the new one made implausible goes now, so that the next rounds try what it had stood in for
        # (MRCLAM robot 2: landmark_bias named at tau 50 s, 104 s once the lag was in, and dropped only after the
        # last round, which had found beacon_height_scale's gain taken by it)
        st.current, st.current_ll = drop_implausible(st.named, st.current, st.current_ll, ctx, progress)


def finish(st: SearchState, ctx: SearchContext, workers: Any, max_rounds: int,
           progress: Callable[[str], None]) -> dict[str, Any]:
    """After the rounds: what the limit of rounds left significant, the backward check (:func:`prune`) and the "none
    of the above" probes; the keys of :func:`search`'s result that the rounds make."""
    capped = len(st.rounds) == max_rounds and len(st.winners) == len(st.rounds) and len(st.remaining) > 0
    left = [c.name for c in st.rounds[-1] if c.significant and c.name != st.winners[-1]] if capped else []
    if left:
        progress(f"stopped: the search runs at most {max_rounds} round{'s' if max_rounds != 1 else ''} (--rounds), and "
                 f"{', '.join(left)} {'was' if len(left) == 1 else 'were'} still significant in the last")
    named = list(st.named)
    current, _ = prune(named, st.current, st.current_ll, ctx, workers, progress)
    last = st.last if st.last is not None and st.last.current is current else None
    probes = none_of_the_above(current, last, ctx, workers, progress)
    return {"rounds": st.rounds, "named": named, "model": current, "escapes": st.escapes, "probes": probes,
            "max_rounds": max_rounds, "winners": st.winners, "left_at_cap": left, "state": st}


def search(logs: list[Trajectory], candidates: list[str], opts: EMOptions, jobs: int = 2,
           progress: Callable[[str], None] = print, action_model: str | None = None,
           pool: Any = None, max_rounds: int = MAX_ROUNDS) -> dict[str, Any]:
    """The whole search (module docstring), at most ``max_rounds`` rounds: returns the base fit, every round's
    candidates, the named effects in order (``"winners"``: each round's, pruned ones included; ``"left_at_cap"``: the
    candidates still significant in the last round when the search stopped at ``max_rounds``, which another round
    would have tried again), and the current model after each addition (all fitted on the training half),
    the logs without outliers that every score uses (``"outliers"``: how many of how many sightings were set aside;
    ``"map_check"``: the landmarks whose sightings the base model's map does not explain, ``learners.em.map_check``,
    and where ``opts.map_repair`` found pairs that may be swapped, ``"map_repair"``, ``map_check.repair_record``: the
    base fitted on the logs with their ids exchanged, and where that holds, every fit here, the base's too, made on
    the repaired logs, which ``"logs"`` then are; ``"bearing_sign"``: ``learners.em.bearing_sign.sign_check``'s record
    of the base, None where its bearings looked right),
    the candidates the logs cannot support (``"skipped"``: name -> what the log lacks), the fits' context
    (``"context"``: a refit on the training halves) and where the rounds stand (``"state"``, :class:`SearchState`).
    ``action_model``: of the base fit (``aibo learn --action-model``). ``pool``: a worker pool of ``jobs`` workers to run in
    (``aibo_core.workers.process_pool``; the caller's, left open), else one of its own."""
    t0 = time.perf_counter()
    repair_map = opts.map_repair
    opts = opts.comparable()  # every fit of the search is compared with another: converged to 0.1 nats (EMOptions)
    given = logs
    base, refit, logs, n_out = base_and_outliers(logs, opts, action_model, progress)
    # landmarks the map misplaces (their sightings are outliers here): judged by the base on every sighting
    judgement = judged(base, make_batch(given), DEFAULT_GATE) if given else None
    mapped, left_out = (judgement.found, judgement.left_out) if judgement else ([], 0)
    map_repair, tries = None, exchanges(mapped) if repair_map else []
    if tries:  # as ``aibo learn`` does (``EMOptions.map_repair``)
        def fit(fixed: list[Trajectory]) -> tuple[tuple, Model]:
            tried = base_and_outliers(fixed, opts, action_model, progress)
            return tried, tried[0]

        records, tried, fixed = tried_exchanges(given, tries, left_out, DEFAULT_GATE, fit)
        for record in records:
            progress(f"  the map and the sightings disagree (report.json: map_check, map_repair): "
                     f"{repair_warning(record)}")
        map_repair = records[-1] if tried is not None else records[0]
        if tried is not None:  # the search runs on the repair
            given, (base, refit, logs, n_out) = fixed, tried
    # bearings of the other sign (a range sensor's, as ``aibo learn`` checks): said here, the search goes on as given
    bearing_sign = sign_check(given, base, opts) if given else None
    for warning in sign_warnings(bearing_sign):
        progress(f"  {warning}")
    n_sightings = sum(tr.n_sightings for tr in given)
    train = [training_log(tr) for tr in logs]
    # candidates are warm-started
    opts = replace(opts, gate=None, max_iter=min(opts.max_iter, 200), patience=min(opts.patience, SEARCH_PATIENCE))
    ctx = SearchContext(train, logs, opts)
    base = ctx.fit(base)  # polished as the candidates will be: gains are the effects' alone
    base_ll = ctx.loglik(base)
    progress(f"base model fitted on the training half in {time.perf_counter() - t0:.1f} s; {n_out} outlier "
             "sightings set aside")
    if refit is not None:
        progress(f"  it ended in a wrong world ({refit.info.spurious_refit['off_field_fraction']:.0%} of the smoothed "
                 "poses off the field); with spurious sightings in the model it found the field: false_sightings is "
                 "tried from there too")
    in_base = {e.name for e in base.effects}  # fitted by the base itself (a range's shrink: EMOptions.range_shrink)
    remaining = [c for c in candidates if applicable(c, logs) and c not in in_base]
    skipped = {c: "in the base model already (aibo learn fits it on this sensor)" if c in in_base else
               "the log(s) hold no " + ", ".join(NEEDS_WORDS.get(need, need) for need in EFFECT_MODELS[c].NEEDS
                                                 if any(getattr(tr, need) is None for tr in logs))
               for c in candidates if c not in remaining}
    for name, why in skipped.items():
        progress(f"  {name}: not tried ({why})")
    st = SearchState(base, base_ll, remaining,
                     previous={} if refit is None else {"false_sightings": refit.params})
    with process_pool(max(jobs, 1)) if pool is None else nullcontext(pool) as pool:
        workers = pool if jobs > 1 else None
        run_rounds(st, ctx, workers, jobs, max_rounds, progress)
        found = finish(st, ctx, workers, max_rounds, progress)
    return {"base": base, "base_refit": None if refit is None else refit.info.spurious_refit, "logs": logs,
            "outliers": {"set_aside": n_out, "sightings": n_sightings}, "map_check": mapped, "map_repair": map_repair,
            "bearing_sign": bearing_sign, "skipped": skipped, "context": ctx,
            "action_model": action_model, "jobs": jobs, **found}


def search_without(found: dict[str, Any], name: str, pool: Any = None,
                   progress: Callable[[str], None] = print) -> dict[str, Any]:
    """``found`` (:func:`search`'s result) as the search would have ended without candidate ``name``, which a round
    named: the rounds before that one are the same (another candidate won each), so the search runs again from the
    state that round started from, ``name`` left out (a better base model the round's escapes found is kept, though
    ``name``'s fit may have been the one that found it: it only ever raises the likelihood). ``pool``: a worker pool of
    the search's ``jobs`` workers (None: this process).

    Why: the final fit on the whole logs can make a named effect implausible (``final.plausible_diagnosis`` drops it);
    the round that named it then never gave its runner-up a chance. MRCLAM robot 3 (whole log): ``landmark_bias``
    won round 3 over ``beacon_height_scale`` (held-out +212 nats), then went to a correlation time of 734 s in the
    final fit; without it as a candidate, ``beacon_height_scale`` is named, the calibrated check's disagreements
    fall from 9 to 5 and the forward speed against Vicon is within 2% (docs/results.md, "An effect dropped in the
    final fit"). Every effect the final fit dropped before (``found["dropped_in_final"]``) is left out too: a round
    earlier than the one that named it would otherwise try it again."""
    st0: SearchState = found["state"]
    k = st0.winners.index(name)
    start = st0.starts[k]
    left_out = {name} | {d["name"] for d in found.get("dropped_in_final", [])}
    st = SearchState(start.current, start.current_ll, [n for n in start.remaining if n not in left_out],
                     rounds=st0.rounds[:k],
                     named=list(start.named), winners=st0.winners[:k], starts=st0.starts[:k],
                     escapes=[e for e in st0.escapes if e["round"] <= k + 1],  # the round's own: in its start
                     previous=dict(start.previous))
    progress(f"the search again from round {k + 1}, without " + ", ".join(sorted(left_out & set(start.remaining))))
    ctx, jobs = found["context"], found.get("jobs", 1)
    workers = pool if jobs > 1 else None
    run_rounds(st, ctx, workers, jobs, found["max_rounds"], progress)
    return dict(found, **finish(st, ctx, workers, found["max_rounds"], progress))


def none_of_the_above(current: Model, last: SearchContext | None, ctx: SearchContext, pool: Any,
                      progress: Callable[[str], None]) -> list[Candidate]:
    """The final check: every probe (``learners.model.probes``: a speed that depends on the heading or the position,
    effects outside the catalogue) fitted on the search's final model ``current`` and tested as the candidates are,
    the probes sharing the level ``ALPHA``. ``last``: the last round's context when its null was ``current``'s
    (else refitted). A significant probe is a dependence no named effect explains: the report's "none of the
    above"."""
    probe_ctx = (replace(last, n_tests=len(PROBES)) if last is not None
                 else with_null(ctx, current, len(PROBES)))
    tried = pool_map(pool, run_trial, [Trial(n, probe_ctx, probe=True) for n in PROBES])
    progress("none of the above? (effects outside the catalogue, on the final model)")
    _say_round(tried, progress)
    return tried
