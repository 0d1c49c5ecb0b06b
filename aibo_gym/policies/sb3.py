"""``sb3``: a trained Stable-Baselines3 explorer (``aibo train-explorer``) choosing each held command.

Parameters: ``path`` (the agent ``.zip``; spec shorthand ``"sb3:AGENT.zip"``), ``hold_s`` (default:
the one it was trained with, from the ``AGENT.json`` written beside it, else 5 s),
``deterministic`` (take the most probable command; default false: a PPO agent's command is drawn
from its action distribution with the policy's own seeded RNG, since the argmax of a briefly
trained policy collapses onto a few commands; a DQN agent always takes its best Q), ``shield`` (replace a command whose predicted
path leaves the field by the safe one of most similar attempted velocity: the field-keeping rule
of :func:`aibo_gym.explorer.shield_command`, applied in training too), ``margin_mm``. Its observation is
:meth:`OnboardTracker.features` (onboard only). SB3 is imported only when this policy is built;
a missing file or an agent for another observation or action space is one ValueError line.
"""

from __future__ import annotations

import hashlib
import json
import os
from typing import Any

import numpy as np

from aibo_core.actions import N_ACTIONS

from .base import HoldPolicy, register_policy
from .onboard import FEATURES_VERSION, N_FEATURES

ALGOS = ("ppo", "dqn")


def sidecar_path(path: str) -> str:
    root = path[:-4] if path.endswith(".zip") else path
    return root + ".json"


#: How to install Stable-Baselines3 (the ``agents`` extra): a CPU-only torch first, or pip pulls gigabytes of CUDA wheels.
AGENTS_HINT = ("install a CPU-only torch first (pip install torch --index-url https://download.pytorch.org/whl/cpu), "
               "then pip install -e '.[agents]' (docs/environments.md)")


def _sha256(path: str) -> str:
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def load_agent(path: str, features: str = FEATURES_VERSION, n_features: int = N_FEATURES, policy: str = "sb3"):
    """(SB3 model, its metadata dict) of an agent file for the observation ``features`` (its version,
    ``n_features`` long) of ``policy``; ValueError naming the file otherwise."""
    if not os.path.isfile(path) and os.path.isfile(path + ".zip"):
        path = path + ".zip"
    if not os.path.isfile(path):
        raise ValueError(f"{policy} agent {path!r}: no such file (train one with 'aibo train-explorer')")
    meta: dict[str, Any] = {}
    side = sidecar_path(path)
    if os.path.isfile(side):
        try:
            with open(side) as f:
                meta = json.load(f)
        except (OSError, ValueError) as exc:
            raise ValueError(f"{policy} agent {side!r}: unreadable metadata ({exc})") from None
    if "agent_sha256" in meta and meta["agent_sha256"] != _sha256(path):
        raise ValueError(f"{policy} agent {path!r}: its description {side!r} belongs to another agent (SHA-256 "
                         "differs); retrain it or restore the pair")
    if meta.get("features", features) != features:
        raise ValueError(f"{policy} agent {path!r}: trained on observation '{meta.get('features')}', this policy builds "
                         f"'{features}' (retrain it, or use the policy it was trained for)")
    try:
        import stable_baselines3 as sb3
    except ImportError:
        raise ValueError(f"policy '{policy}' needs Stable-Baselines3: {AGENTS_HINT}") from None
    algos = [meta["algo"]] if meta.get("algo") in ALGOS else list(ALGOS)
    model, errors = None, []
    for algo in algos:
        try:
            model = getattr(sb3, algo.upper()).load(path, device="cpu")
            break
        except Exception as exc:  # noqa: BLE001 - any failure to read it is reported in one line
            errors.append(f"{algo}: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}")
    if model is None:
        raise ValueError(f"{policy} agent {path!r}: not a readable SB3 agent ({'; '.join(errors)})")
    obs_shape = tuple(getattr(model.observation_space, "shape", ()) or ())
    n_act = getattr(model.action_space, "n", None)
    if obs_shape != (n_features,) or n_act != N_ACTIONS:
        raise ValueError(f"{policy} agent {path!r}: observation {obs_shape} and {n_act} actions do not match this policy's "
                         f"({n_features},) onboard features and {N_ACTIONS} commands (an agent for another env?)")
    return model, meta


@register_policy
class SB3Policy(HoldPolicy):
    name = "sb3"
    defaults = {"path": "", "hold_s": None, "margin_mm": 300.0, "deterministic": False, "shield": True}

    def __init__(self, config, seed=None, **params) -> None:
        super().__init__(config, seed=seed, **params)
        self.model, self.meta = load_agent(self.params["path"])
        if self.params["hold_s"] is None:
            self.set_hold(float(self.meta.get("hold_s", 5.0)))
        self.max_steps = int(self.meta.get("episode_steps", self.cfg["max_steps"]))

    def choose(self) -> int:
        obs = self.tracker.features(self.max_steps)
        pref = action_preferences(self.model, obs)
        if self.params["deterministic"] or not hasattr(self.model.policy, "get_distribution"):
            a = int(np.argmax(pref))
        else:  # sample the trained stochastic policy with the policy's own seeded RNG (reproducible logs)
            p = np.exp(pref - pref.max())
            a = int(self.rng.choice(N_ACTIONS, p=p / p.sum()))
        if not self.params["shield"]:
            return a
        from ..explorer import shield_command

        return shield_command(self.tracker, a, self.hold_s, self.margin)


def action_preferences(model, obs: np.ndarray) -> np.ndarray:
    """(40,) the agent's preference per command: PPO's logits or DQN's Q-values."""
    import torch

    with torch.no_grad():
        t, _ = model.policy.obs_to_tensor(obs)
        if hasattr(model.policy, "get_distribution"):
            return model.policy.get_distribution(t).distribution.logits.cpu().numpy().reshape(-1)
        return model.q_net(t).cpu().numpy().reshape(-1)
