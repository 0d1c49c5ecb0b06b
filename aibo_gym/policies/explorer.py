"""``explorer``: the shipped learned explorer (``aibo train-explorer``), an SB3 agent that sees the
running onboard information and chooses each held command.

It keeps the same onboard information as ``greedy`` (:class:`~aibo_gym.policies.greedy.GreedyPolicy`:
a 3 x 3 information block per command's velocity and one for the sensor curve, updated after each
hold from the sightings reported) and every ``hold_s`` seconds feeds the agent
:meth:`ExplorerPolicy.observation` (``INFO_FEATURES``): the onboard EKF head of
:meth:`OnboardTracker.features` (pose, its std, time, head-pan phase), per command the log det of
its information over the prior, the sensor curve's, and per command the one-step gain ``greedy``
predicts for holding it (-1 for commands whose path would leave the field). The agent was trained
(:mod:`aibo_gym.train`) with the dense reward of the increase of :meth:`GreedyPolicy.logdet` per
hold, robots resampled every episode. The command it picks goes through the field-keeping shield
(:func:`aibo_gym.explorer.shield_command`).

Parameters: ``path`` (default ``""``: the agent shipped in ``aibo_gym/agents/explorer.zip``),
``deterministic`` (the most probable command; default false: drawn from the agent's distribution
with the policy's seeded RNG), ``shield``, ``hold_s``, ``margin_mm``, ``sensor_weight``,
``path_points`` (as ``greedy``'s). Needs Stable-Baselines3 (the ``agents`` extra).

Measured (``aibo experiment policies``, robots 201-220, never trained on; paired over 20 seeds,
mean velocity error against random-balanced / informed): 5 min -15.0 ± 2.8% / +4.6 ± 2.5%,
15 min -10.1 ± 2.5% / +4.6 ± 2.5%: as good as ``greedy``, not better, and short of issue 20's
target (-30% / -10%); see docs/results.md, "The learned explorer on held-out robots".
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from aibo_core.actions import N_ACTIONS

from .base import register_policy
from .greedy import GreedyPolicy

INFO_FEATURES = "info-v1"
N_HEAD = 10  # the head of OnboardTracker.features: pose, its std, elapsed fraction, head-pan phase
N_INFO_FEATURES = N_HEAD + 2 * N_ACTIONS + 1
VELOCITY_LOGDET_SCALE = 30.0  # nats: a command's information 1e4 x its prior in each of 3 components is ~0.9
SENSOR_LOGDET_SCALE = 60.0  # nats
GAIN_SCALE = 10.0  # nats per hold
UNSAFE = -1.0  # the gain feature of a command whose predicted path leaves the field
SHIPPED_AGENT = Path(__file__).resolve().parent.parent / "agents" / "explorer.zip"
EPISODE_STEPS = 27000  # frames: the elapsed-fraction feature is over 15 minutes, whatever the log's length


@register_policy
class ExplorerPolicy(GreedyPolicy):
    name = "explorer"
    defaults = {**GreedyPolicy.defaults, "path": "", "deterministic": False, "shield": True}

    def __init__(self, config, seed=None, **params) -> None:
        super().__init__(config, seed=seed, **params)
        self.model = self.load()

    def load(self):
        """The SB3 agent of ``path`` (the shipped one if empty); ValueError (one line) if unusable."""
        from .sb3 import load_agent

        path = self.params["path"] or str(SHIPPED_AGENT)
        model, meta = load_agent(path, features=INFO_FEATURES, n_features=N_INFO_FEATURES, policy=self.name)
        if meta.get("policy") not in (None, self.name):
            raise ValueError(f"explorer agent {path!r}: trained for policy {meta.get('policy')!r}, not 'explorer'")
        return model

    def reset(self, info=None) -> None:
        super().reset(info)
        self._cached: tuple[int, np.ndarray] | None = None

    def observation(self) -> np.ndarray:
        """(N_INFO_FEATURES,) float32 in [-5, 5]: see the module docstring (``INFO_FEATURES``); computed
        once per frame (call it after the hold's information is added)."""
        if self._cached is not None and self._cached[0] == self.tracker.steps:
            return self._cached[1]
        head = self.tracker.features(EPISODE_STEPS)[:N_HEAD]
        cand, gain = self.gains()
        predicted = np.full(N_ACTIONS, UNSAFE)
        predicted[cand] = gain / GAIN_SCALE
        out = np.concatenate([head, self.velocity_logdet() / VELOCITY_LOGDET_SCALE,
                              [self.sensor_logdet() / SENSOR_LOGDET_SCALE], predicted])
        obs = np.clip(out, -5.0, 5.0).astype(np.float32)
        self._cached = (self.tracker.steps, obs)
        return obs

    def choose(self) -> int:
        self._close_hold()
        a = self.decide(self.observation())
        if self.params["shield"]:
            from ..explorer import shield_command

            a = shield_command(self.tracker, a, self.hold_s, self.margin)
        self._open_hold()
        return a

    def decide(self, obs: np.ndarray) -> int:
        """The agent's command for ``obs`` (before the shield)."""
        from .sb3 import action_preferences

        pref = action_preferences(self.model, obs)
        if self.params["deterministic"]:
            return int(np.argmax(pref))
        p = np.exp(pref - pref.max())
        return int(self.rng.choice(N_ACTIONS, p=p / p.sum()))


class DrivenExplorer(ExplorerPolicy):
    """The explorer's onboard state with the command imposed (``pending``, set by the training env
    :class:`aibo_gym.explorer.InfoExplorerEnv`): no agent is loaded."""

    pending = 0

    def load(self):
        return None

    def decide(self, obs: np.ndarray) -> int:
        return int(self.pending)


def teacher_action(obs: np.ndarray) -> int:
    """``greedy``'s choice read off an explorer observation: the largest predicted gain (first on ties)."""
    return int(np.argmax(obs[N_HEAD + N_ACTIONS + 1:]))

