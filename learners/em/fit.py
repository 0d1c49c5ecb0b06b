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

from learners.em.accel import Packer, squarem_step
from learners.inference.batch import Batch
from learners.inference.lowered import Lowered
from learners.inference.posterior import Posterior
from learners.model.model import Model

#: First-iteration outlier gate on the innovation's Mahalanobis^2 (2 dof: p = 1.4e-11). Not the
#: chi-square 0.999 quantile (13.8): with the paper's very poor start that prunes ~12% of honest
#: sightings and biases sigma_angle by ~20% (README, "Options").
DEFAULT_GATE = 50.0
#: Sensor curve degree per basis when ``EMOptions.degree`` is None: the paper's cubic in d; c0 + c1/d + c2/d^2.
DEFAULT_DEGREE = {"power": 3, "inverse": 2}
#: The sensor basis of a fresh start when ``EMOptions.basis`` is None, per sensor kind: a pinhole height
#: is c1/d (README, "EM at the information bound"); a range is d.
DEFAULT_BASIS = {"height_px": "inverse", "range_mm": "power"}
#: The switch to the scoring finish (``EMOptions.switch_gain``) looks at the best likelihood's gain over
#: this many iterations, and not before this many E-steps (the screening's included).
SWITCH_WINDOW = 10
SWITCH_MIN_ITER = 60


@dataclass
class EMOptions:
    """Every knob of the EM fit. Defaults follow the measured evidence (README, "Options");
    ``EMOptions.paper()`` is the paper's recipe as written."""

    max_iter: int = 3000
    patience: int = 50  # paper: stop after 50 iterations without a new highest likelihood
    gate: float | None = DEFAULT_GATE  # first-iteration Mahalanobis^2 gate; None disables pruning
    sensor_method: str = "cubature"  # paper: "sample" (one draw per sighting); deterministic: "cubature"
    n_samples: int = 1  # paper: one sample per frame (method "sample")
    basis: str | None = None  # sensor curve basis: "power" (paper) or "inverse"; None: --init's, else DEFAULT_BASIS
    degree: int | None = None  # sensor curve degree; None: DEFAULT_DEGREE of the basis (paper: cubic)
    learn_motion_noise: bool = True  # paper: fixed Sigma_A (10 mm, 10 mm, 0.1 rad)
    estep: str = "compiled"  # "compiled" (numba) or "numpy" (the per-step reference)
    accel: str = "squarem"  # paper: "none"; "squarem": extrapolated EM with a monotone safeguard
    min_improvement: float = 0.1  # a new best must beat the old by this (nats); paper: any amount
    starts: int = 3  # starts screened, the most likely continued (``learners.em.starts``); paper: 1
    screen_iter: int = 30  # EM iterations each start runs before the most likely is chosen
    alias_search: bool = True  # search heading aliases after the fit (``learners.em.alias``); paper: off
    # continuous commands: after the fit, profile an actuation lag and keep it when significant (``learners.em.lag``)
    lag_search: bool = True
    uncertainty: bool = True  # standard errors from the Fisher information (``learners.em.uncertainty``)
    # after EM: "none" (EM's own stop, as the paper) or "scoring": EM stops early and Fisher scoring climbs to
    # the likelihood's maximum (``learners.em.finish``; off by default: README, "EM at the information bound")
    finish: str = "none"
    switch_gain: float = 1.0  # with the finish, EM stops once SWITCH_WINDOW iterations gained less (nats)
    seed: int = 0
    frozen: tuple[str, ...] = ()  # effects held at their values (profile likelihood), by name

    @classmethod
    def paper(cls, **overrides) -> "EMOptions":
        """The paper's recipe: fixed motion noise, one sample per sighting, plain EM, strict stop rule."""
        base = dict(sensor_method="sample", learn_motion_noise=False, accel="none", min_improvement=0.0,
                    basis="power", degree=3, starts=1, alias_search=False, lag_search=False)
        return cls(**{**base, **overrides})

    def validate(self) -> "EMOptions":
        if self.sensor_method not in ("sample", "cubature"):
            raise ValueError(f"sensor_method must be 'sample' or 'cubature', got {self.sensor_method!r}")
        if self.accel not in ("none", "squarem"):
            raise ValueError(f"accel must be 'none' or 'squarem', got {self.accel!r}")
        if self.estep not in ("compiled", "numpy"):
            raise ValueError(f"estep must be 'compiled' or 'numpy', got {self.estep!r}")
        if self.finish not in ("none", "scoring"):
            raise ValueError(f"finish must be 'none' or 'scoring', got {self.finish!r}")
        if self.basis is not None and self.basis not in DEFAULT_DEGREE:
            raise ValueError(f"basis must be 'power' or 'inverse', got {self.basis!r}")
        for name in ("max_iter", "patience", "n_samples", "degree", "starts", "screen_iter"):
            if getattr(self, name) is not None and getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        return self

    def sensor_basis(self, kind: str = "height_px", init_basis: str | None = None) -> str:
        """The basis of the fit: the option, else the start model's (``init_basis``), else DEFAULT_BASIS
        of the sensor ``kind``."""
        return self.basis or init_basis or DEFAULT_BASIS[kind]

    def sensor_degree(self, basis: str) -> int:
        """The curve's degree: the option, else DEFAULT_DEGREE of ``basis``."""
        return self.degree if self.degree is not None else DEFAULT_DEGREE[basis]


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
    starts: list = field(default_factory=list)  # the screening report (``learners.em.starts``), JSON-able


def e_step(params: Model, batch: Batch, estep: str, gate: float | None = None,
           reuse: Posterior | None = None, lo: Lowered | None = None) -> Posterior:
    """The E-step; ``reuse``: a spent Posterior whose memory the compiled kernel may overwrite;
    ``lo``: ``params.lower(batch)`` if the caller has it.

    When an effect of ``params`` is a mixture (``false_sightings``), the Posterior's ``loglik`` is
    the mixture's one-step predictive log-likelihood (``learners.inference.predictive``), not the
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
    from learners.inference.predictive import has_mixture, sightings_logdens

    if has_mixture(params):
        idx = np.flatnonzero(batch.used & ~(post.mahal2 > (gate if gate is not None else np.inf)))
        post.loglik = float(np.sum(sightings_logdens(params, batch, post, idx, lo)))
    return post


def m_step(params: Model, batch: Batch, post: Posterior, rng: np.random.Generator, opts: EMOptions,
           lo: Lowered | None = None) -> Model:
    """New model from the E-step's beliefs (paper section III; ``mstep``)."""
    from learners.em.mstep import maximize

    return maximize(params, batch, post, rng, opts, lo)


def initial_state(start: Model, batch: Batch, opts: EMOptions) -> EMState:
    return EMState(
        iteration=0, params=start, best=start, best_loglik=-np.inf, best_iteration=-1, loglik=[],
        used=batch.used.copy(), pruned=0, rng_state=np.random.default_rng(opts.seed).bit_generator.state,
    )


class _Loop:
    """One fit's bookkeeping: every E-step is an iteration (pruning, likelihood, best, stop rule)."""

    def __init__(self, batch: Batch, state: EMState, opts: EMOptions, on_iteration, on_cycle, switch: bool):
        self.state, self.opts, self.switch = state, opts, switch
        self.batch = batch.with_used(state.used)
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

    def m(self, params: Model, post: Posterior) -> Model:
        lo = self.lowered[1] if self.lowered[0] is params else None  # lowered by the E-step just run
        return m_step(params, self.batch, post, self.rng, self.opts, lo)

    def end_cycle(self, next_params: Model) -> None:
        self.state.params = next_params
        self.state.rng_state = self.rng.bit_generator.state
        if self.on_cycle is not None:
            self.on_cycle(self.state)

    def em_cycle(self) -> None:
        post, _ = self.evaluate(self.state.params)
        self.end_cycle(self.m(self.state.params, post))

    def squarem_cycle(self, packer: Packer) -> None:
        """Two EM steps, one extrapolated jump, kept only if its likelihood is no worse (safeguard)."""
        p0 = self.state.params
        post0, _ = self.evaluate(p0)
        p1 = self.m(p0, post0)
        if self.done():
            return self.end_cycle(p1)
        post1, ll1 = self.evaluate(p1)
        p2 = self.m(p1, post1)
        x, a = squarem_step(packer.pack(p0), packer.pack(p1), packer.pack(p2))
        if a == -1.0 or self.done():
            return self.end_cycle(p2)
        try:
            jump = packer.unpack(x, like=p2)
            post_j, ll_j = self.evaluate(jump)
        except (FloatingPointError, np.linalg.LinAlgError, ValueError):
            return self.end_cycle(p2)
        self.end_cycle(self.m(jump, post_j) if ll_j >= ll1 else p2)


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
    while not loop.done():
        if packer is None:
            loop.em_cycle()
        else:
            loop.squarem_cycle(packer)
    return state


def options_json(opts: EMOptions) -> str:
    return json.dumps(asdict(opts), sort_keys=True)
