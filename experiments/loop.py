"""The one collect -> learn -> score loop (``aibo reproduce``, ``aibo bench``, ``scripts/compare_options.py``
and the experiment sweeps all use it)."""

from __future__ import annotations

from typing import Any

import numpy as np

from aibo_core.trajectory import Trajectory
from learners.arrays.batch import make_batch
from learners.base import LearnResult, ProgressFn
from learners.em.estep import e_step
from learners.em.learner import EMLearner
from learners.em.options import EMOptions
from learners.metrics import model_errors
from learners.model.model import Model


def simulate(config: dict[str, Any] | None, steps: int, seed: int, policy: Any = "random-balanced",
             policy_params: dict[str, Any] | None = None, progress: bool = False) -> Trajectory:
    """A simulated log: ``steps`` frames of the env ``config`` under the policy spec, seeded by ``seed``
    (``aibo_gym.collect.collect``; a config without ``max_steps`` gets one when ``steps`` is longer
    than the default episode)."""
    from aibo_gym.collect import collect
    from aibo_gym.config import default_config

    cfg = config
    if steps > default_config()["max_steps"] and "max_steps" not in (config or {}):
        cfg = {**(config or {}), "max_steps": steps}
    return collect(cfg, steps=steps, seed=seed, policy=policy, policy_params=policy_params, progress=progress)


def fit_em(logs: list[Trajectory], options: EMOptions | None = None, init: Model | None = None,
           progress: ProgressFn | None = None, checkpoint_path=None, **learner_args) -> LearnResult:
    """EM (``learners.em.learner.EMLearner``) from the paper's start, or from ``init``."""
    return EMLearner(options or EMOptions(), checkpoint_path=checkpoint_path, **learner_args).fit(
        logs, init=init, progress=progress)


def score(params: Model, logs: list[Trajectory]) -> dict[str, float]:
    """The paper's errors of ``params`` against the logs' truth (``learners.metrics.model_errors``)."""
    return model_errors(params, logs).as_dict()


def heldout_loglik(params: Model, log: Trajectory, estep: str = "compiled") -> float:
    """Predictive log-likelihood per sighting (nats) of an independent ``log`` of the same robot
    under the learned model: the E-step's sum of one-step predictive log densities
    (``Posterior.loglik``) divided by the sightings; the model's start belief is kept."""
    batch = make_batch([log])
    model = EMLearner().start_params([log], params, batch)
    post = e_step(model, batch, estep)
    return float(post.loglik) / max(int(batch.used.sum()), 1)


def log_stats(tr: Trajectory) -> dict[str, float]:
    """What the policy gathered: sightings, the share of frames with one, commands used."""
    from aibo_core.trajectory import sightings_per_frame

    return {"frames": int(tr.n_frames), "sightings": int(tr.n_sightings),
            "seen_share": float((sightings_per_frame(tr) > 0).mean()),
            "commands_used": int(len(np.unique(tr.actions)))}
