"""The EM loop: E-step, M-step, first-iteration outlier gating, the paper's stop rule, resumable state.

Inference (``learners.inference``) works on the model lowered to arrays (``Model.lower``); the
M-step (``mstep``) turns its statistics into new components. Both are pure functions of
(model, data); this module only sequences them and keeps the books.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from typing import Callable

import numpy as np

from learners.arrays.batch import Batch
from learners.arrays.lowered import Lowered
from learners.arrays.posterior import Posterior
from learners.em.accel import Packer, squarem_step
from learners.em.estep import e_step, forward_loglik
from learners.em.mstep import maximize
from learners.em.options import DEFAULT_GATE, SWITCH_MIN_ITER, SWITCH_WINDOW, EMOptions
from learners.model.model import Model

#: At most this many polish steps per fit (``EMOptions.polish``). Each is a few dozen forward passes; on 5-minute
#: ``landmark_bias`` logs the first gained 0.8-3 nats and the later ones 0.01-0.2 (docs/results.md, calibration).
POLISH_ROUNDS = 5

# re-exported: scripts written against the earlier layout import these from here (their home: ``options``, ``estep``)
__all__ = ["DEFAULT_GATE", "EMOptions", "EMState", "e_step", "m_step", "initial_state", "run", "options_json"]


@dataclass
class EMState:
    """Everything a fit needs to continue: saved in checkpoints."""

    iteration: int  # E-steps done
    params: Model  # parameters for the next E-step
    best: Model
    best_loglik: float
    best_iteration: int  # iteration (0-based) of ``best``, the highest likelihood so far
    loglik: list[float]
    used: np.ndarray  # sighting mask after first-iteration pruning
    pruned: int
    rng_state: dict
    converged: bool = False
    seconds: list[float] = field(default_factory=list)
    record_iteration: int = -1  # last iteration that beat the best by more than min_improvement
    polishes: int = 0  # polish steps taken after convergence (``EMOptions.polish``)
    starts: list = field(default_factory=list)  # the screening report (``learners.em.starts``), JSON-able
    #: EM steps whose log-likelihood fell: [iteration (0-based) of the model it fell to, the loglik of the model
    #: stepped from, the one fallen to]
    #: (``_Loop.step_from``; ``setback_from_best``)
    setbacks: list = field(default_factory=list)
    step_ref: float | None = None  # log-likelihood of the model whose M-step gave ``params`` (None: no EM step's)
    #: rad: the bearing noise of the start model, with which the fit takes the image angle's expectation throughout
    #: (``Batch.angle_noise``; regression calibration's measurement error taken as known: with it following the
    #: model's, the sensor M-step ignored what it moves and fits became sensitive to rounding; from the paper's start,
    #: 0.2 rad, the observed phi^2 as it is: docs/results.md "The range curve freed by default"); None: the model's
    #: own (a checkpoint written before it)
    angle_noise: float | None = None


def setback_from_best(state: EMState, within: float = 1.0) -> tuple[float, int]:
    """(nats, 1-based iteration) of the largest fall of one EM step taken from a model within ``within`` nats of the
    fit's best ((0.0, 0): none). A fall far from the best is EM finding its way from a poor start (an effect-free
    5-minute ``aibo`` log fell 994 nats at iteration 6 and ended well); a fall from the best means EM does not hold
    the model it returns: the fit kept its most likely iterate, which need not be the likelihood's maximum."""
    falls = [(ref - ll, it + 1) for it, ref, ll in state.setbacks if ref >= state.best_loglik - within]
    return max(falls, default=(0.0, 0))


def m_step(params: Model, batch: Batch, post: Posterior, rng: np.random.Generator, opts: EMOptions,
           lo: Lowered | None = None) -> Model:
    """New model from the E-step's beliefs (paper section III; ``mstep``)."""
    return maximize(params, batch, post, rng, opts, lo)


def initial_state(start: Model, batch: Batch, opts: EMOptions) -> EMState:
    return EMState(
        iteration=0, params=start, best=start, best_loglik=-np.inf, best_iteration=-1, loglik=[],
        used=batch.used.copy(), pruned=0, rng_state=np.random.default_rng(opts.seed).bit_generator.state,
        angle_noise=float(start.sensor.sigma_bearing),
    )


class _Loop:
    """One fit's bookkeeping: every E-step is an iteration (pruning, likelihood, best, stop rule)."""

    def __init__(self, batch: Batch, state: EMState, opts: EMOptions, on_iteration, on_cycle, switch: bool):
        self.state, self.opts, self.switch = state, opts, switch
        self.batch = batch.with_used(state.used).with_angle_noise(state.angle_noise)
        self.rng = np.random.default_rng()
        self.rng.bit_generator.state = state.rng_state
        self.on_iteration, self.on_cycle = on_iteration, on_cycle
        self.tick = time.perf_counter()
        self.spent: Posterior | None = None
        self.lowered: tuple[Model | None, Lowered | None] = (None, None)

    def done(self) -> bool:
        return self.state.converged or self.state.iteration >= self.opts.max_iter

    def evaluate(self, params: Model) -> tuple[Posterior, float]:
        """E-step at ``params``; the first one prunes outliers (paper section IV-A)."""
        st, opts = self.state, self.opts
        first = st.iteration == 0
        self.lowered = (params, params.lower(self.batch))
        post = e_step(params, self.batch, opts.estep, opts.gate if first else None, reuse=self.spent,
                      lo=self.lowered[1])
        self.spent = post  # its M-step runs before the next E-step, which may then overwrite it
        if first and opts.gate is not None:
            pruned = self.batch.used & (post.mahal2 > opts.gate)
            st.pruned = int(pruned.sum())
            self.batch = self.batch.with_used(self.batch.used & ~pruned)
            st.used = self.batch.used.copy()
            if st.pruned and self.lowered[1].extra is not None:
                # states allocated by the sightings (landmark_bias's slots): lowered again on the kept ones, so the
                # M-step's schedule and the posterior's states agree
                self.lowered = (params, params.lower(self.batch))
                post = e_step(params, self.batch, opts.estep, lo=self.lowered[1])
                self.spent = post
        ll = float(post.loglik)
        if not np.isfinite(ll):
            raise FloatingPointError(f"log-likelihood is {ll} at EM iteration {st.iteration + 1}")
        st.loglik.append(ll)
        if ll > st.best_loglik + opts.min_improvement:
            st.record_iteration = st.iteration
        if ll > st.best_loglik:  # kept even when it is no new record (better by < min_improvement)
            st.best, st.best_loglik, st.best_iteration = params, ll, st.iteration
        st.iteration += 1
        st.converged = st.iteration - 1 - st.record_iteration >= opts.patience
        if self.switch and not st.converged:
            st.converged = self.switch_now()
        now = time.perf_counter()
        st.seconds.append(now - self.tick)
        self.tick = now
        if self.on_iteration is not None:
            self.on_iteration(st, params, ll)
        return post, ll

    def switch_now(self) -> bool:
        """Whether the best likelihood gained less than ``switch_gain`` over the last SWITCH_WINDOW iterations."""
        ll = self.state.loglik
        if self.state.iteration < max(SWITCH_MIN_ITER, SWITCH_WINDOW + 1):
            return False
        return self.state.best_loglik - max(ll[:-SWITCH_WINDOW]) < self.opts.switch_gain

    def step_from(self, ll: float, ref: float | None) -> None:
        """Books an EM step that went from a model of log-likelihood ``ref`` (None: no EM step, e.g. the first
        iteration or a polished model) to one of ``ll``. With an exact E-step EM never falls (Dempster, Laird &
        Rubin 1977); this E-step linearizes (EKF/RTS) and, for a mixture, weighs sightings at the smoothed path, so
        it can. SQUAREM's rejected jumps are not EM steps and are not booked."""
        if ref is not None and ll < ref:
            self.state.setbacks.append([self.state.iteration - 1, ref, ll])

    def m(self, params: Model, post: Posterior) -> Model:
        lo = self.lowered[1] if self.lowered[0] is params else None  # lowered by the E-step just run
        return m_step(params, self.batch, post, self.rng, self.opts, lo)

    def end_cycle(self, next_params: Model) -> None:
        self.state.params = next_params
        self.state.rng_state = self.rng.bit_generator.state
        if self.on_cycle is not None:
            self.on_cycle(self.state)

    def polish(self) -> bool:
        """Once EM has converged (``EMOptions.polish``): every free effect's ``polish`` from the best model, in turn,
        each with the rest held. True when it gained more than ``min_improvement`` nats (one forward pass per model,
        on the fit's sightings): EM then resumes from the polished model (its first E-step sets the new record, and
        the stop rule's patience counts from there)."""
        st, opts = self.state, self.opts
        if not (opts.polish and st.converged and st.polishes < POLISH_ROUNDS and st.iteration < opts.max_iter):
            return False
        loglik = self.loglik
        best, changed = st.best, False
        for effect in st.best.effects:
            if effect.name not in opts.frozen:
                polished = best.effect(effect.name).polish(best, self.batch, loglik)
                if polished is not best.effect(effect.name):
                    best, changed = best.with_effect(polished), True
        st.polishes += 1
        if not changed or loglik(best) <= loglik(st.best) + opts.min_improvement:
            return False
        st.params, st.converged = best, False
        self.state.step_ref = None  # the polished model is no EM step's
        return True

    def loglik(self, params: Model) -> float:
        """``params``' log-likelihood of the fit's sightings (nats): one forward pass, or for a mixture
        (``false_sightings``) the E-step's, which is the mixture's (``e_step``)."""
        from learners.em.predictive import has_mixture

        if has_mixture(params):
            return float(e_step(params, self.batch, self.opts.estep).loglik)
        return forward_loglik(self.batch)(params)

    def em_cycle(self) -> None:
        post, ll = self.evaluate(self.state.params)
        self.step_from(ll, self.state.step_ref)
        self.state.step_ref = ll
        self.end_cycle(self.m(self.state.params, post))

    def squarem_cycle(self, packer: Packer) -> None:
        """Two EM steps, one extrapolated jump, kept only if its likelihood is no worse (safeguard)."""
        p0 = self.state.params
        post0, ll0 = self.evaluate(p0)
        self.step_from(ll0, self.state.step_ref)
        self.state.step_ref = ll0
        p1 = self.m(p0, post0)
        if self.done():
            return self.end_cycle(p1)
        post1, ll1 = self.evaluate(p1)
        self.step_from(ll1, ll0)
        self.state.step_ref = ll1  # p2 = M(p1) is the next model unless a jump is kept
        p2 = self.m(p1, post1)
        x, a = squarem_step(packer.pack(p0), packer.pack(p1), packer.pack(p2))
        if a == -1.0 or self.done():
            return self.end_cycle(p2)
        try:
            jump = packer.unpack(x, like=p2)
            post_j, ll_j = self.evaluate(jump)
        except (FloatingPointError, np.linalg.LinAlgError, ValueError):
            return self.end_cycle(p2)
        if ll_j >= ll1:
            self.state.step_ref = ll_j
            return self.end_cycle(self.m(jump, post_j))
        self.end_cycle(p2)


def run(
    batch: Batch,
    state: EMState,
    opts: EMOptions,
    on_iteration: Callable[[EMState, Model, float], None] | None = None,
    on_cycle: Callable[[EMState], None] | None = None,
    switch: bool = False,
) -> EMState:
    """Iterate EM from ``state`` until the stop rule; returns the final state (best params in ``best``).
    ``switch``: also stop once the likelihood's gain slows below ``opts.switch_gain`` (the caller then
    runs the scoring finish, ``learners.em.finish``).

    ``on_iteration(state, params, loglik)`` follows every E-step; ``on_cycle(state)`` follows every
    point where ``state`` can be saved and resumed exactly (after each EM step, or SQUAREM cycle).
    """
    opts.validate()
    loop = _Loop(batch, state, opts, on_iteration, on_cycle, switch)
    packer = Packer(opts) if opts.accel == "squarem" else None
    while not loop.done() or loop.polish():
        if packer is None:
            loop.em_cycle()
        else:
            loop.squarem_cycle(packer)
    return state


def options_json(opts: EMOptions) -> str:
    return json.dumps(asdict(opts), sort_keys=True)
