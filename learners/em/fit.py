"""The EM loop: E-step, M-step, first-iteration outlier gating, the paper's stop rule, resumable state.

Inference (``smoother``/``kernels``) and the M-steps (``action_mstep``/``sensor_mstep``) are pure
functions of (params, data); this module only sequences them and keeps the books.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from typing import Callable

import numpy as np

from learners.em.action_mstep import action_statistics, update_action_model
from learners.em.data import Batch
from learners.em.params import InitialState, Params
from learners.em.posterior import Posterior
from learners.em.sensor_mstep import update_sensor_model

#: chi-square quantile, 2 degrees of freedom, p = 0.001: a sighting this unlikely is an outlier.
DEFAULT_GATE = 13.8155


@dataclass
class EMOptions:
    """Every knob of the EM fit, with the paper's choices as defaults unless named otherwise."""

    max_iter: int = 3000
    patience: int = 50  # paper: stop after 50 iterations without a new highest likelihood
    gate: float | None = DEFAULT_GATE  # first-iteration Mahalanobis^2 gate; None disables pruning
    sensor_method: str = "sample"  # paper: "sample"; deterministic option: "cubature"
    n_samples: int = 1  # paper: one sample per frame
    degree: int = 3  # paper: cubic
    learn_motion_noise: bool = False  # paper: fixed Sigma_A (10 mm, 10 mm, 0.1 rad)
    estep: str = "compiled"  # "compiled" (numba) or "numpy" (the per-step reference)
    seed: int = 0

    def validate(self) -> "EMOptions":
        if self.sensor_method not in ("sample", "cubature"):
            raise ValueError(f"sensor_method must be 'sample' or 'cubature', got {self.sensor_method!r}")
        if self.estep not in ("compiled", "numpy"):
            raise ValueError(f"estep must be 'compiled' or 'numpy', got {self.estep!r}")
        for name in ("max_iter", "patience", "n_samples", "degree"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        return self


@dataclass
class EMState:
    """Everything a fit needs to continue: saved in checkpoints."""

    iteration: int  # E-steps done
    params: Params  # parameters for the next E-step
    best: Params
    best_loglik: float
    best_iteration: int
    loglik: list[float]
    used: np.ndarray  # sighting mask after first-iteration pruning
    pruned: int
    rng_state: dict
    converged: bool = False
    seconds: list[float] = field(default_factory=list)


def e_step(params: Params, batch: Batch, estep: str, gate: float | None = None) -> Posterior:
    if estep == "compiled":
        from learners.em.kernels import smooth_compiled

        return smooth_compiled(params, batch, gate)
    from learners.em.smoother import smooth

    return smooth(params, batch, gate)


def m_step(params: Params, batch: Batch, post: Posterior, rng: np.random.Generator, opts: EMOptions) -> Params:
    """New (a, b, pi) from the E-step's beliefs (paper section III)."""
    stats = action_statistics
    if opts.estep == "compiled":
        from learners.em.kernels import action_statistics_compiled as stats
    action = update_action_model(params, batch, post, learn_noise=opts.learn_motion_noise, statistics=stats)
    sensor = update_sensor_model(params, batch, post, rng, method=opts.sensor_method,
                                 n_samples=opts.n_samples, degree=opts.degree)
    first = batch.pose_start[:-1]
    init = tuple(InitialState(post.mu_gamma[p].copy(), post.cov_gamma[p].copy()) for p in first)
    return Params(action, sensor, init)


def initial_state(start: Params, batch: Batch, opts: EMOptions) -> EMState:
    return EMState(
        iteration=0, params=start, best=start, best_loglik=-np.inf, best_iteration=-1, loglik=[],
        used=batch.used.copy(), pruned=0, rng_state=np.random.default_rng(opts.seed).bit_generator.state,
    )


def run(
    batch: Batch,
    state: EMState,
    opts: EMOptions,
    on_iteration: Callable[[EMState, Posterior], None] | None = None,
) -> EMState:
    """Iterate EM from ``state`` until the stop rule; returns the final state (best params in ``best``)."""
    opts.validate()
    rng = np.random.default_rng()
    rng.bit_generator.state = state.rng_state
    batch = batch.with_used(state.used)
    while state.iteration < opts.max_iter and not state.converged:
        t0 = time.perf_counter()
        first = state.iteration == 0
        post = e_step(state.params, batch, opts.estep, opts.gate if first else None)
        if first and opts.gate is not None:
            pruned = batch.used & (post.mahal2 > opts.gate)
            state.pruned = int(pruned.sum())
            batch = batch.with_used(batch.used & ~pruned)
            state.used = batch.used.copy()
        ll = float(post.loglik)
        if not np.isfinite(ll):
            raise FloatingPointError(f"log-likelihood is {ll} at EM iteration {state.iteration + 1}")
        state.loglik.append(ll)
        if ll > state.best_loglik:
            state.best, state.best_loglik, state.best_iteration = state.params, ll, state.iteration
        state.params = m_step(state.params, batch, post, rng, opts)
        state.rng_state = rng.bit_generator.state
        state.iteration += 1
        state.seconds.append(time.perf_counter() - t0)
        state.converged = state.iteration - 1 - state.best_iteration >= opts.patience
        if on_iteration is not None:
            on_iteration(state, post)
    return state


def options_json(opts: EMOptions) -> str:
    return json.dumps(asdict(opts), sort_keys=True)
