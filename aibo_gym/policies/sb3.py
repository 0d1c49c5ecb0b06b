"""``sb3``: a trained Stable-Baselines3 explorer (``aibo train-explorer``) choosing each held command.

Parameters: ``path`` (the agent ``.zip``; spec shorthand ``"sb3:AGENT.zip"``), ``hold_s`` (default:
the one it was trained with, from the ``AGENT.json`` written beside it, else 5 s),
``deterministic`` (take the most probable command), ``shield`` (replace a command whose predicted
path leaves the field by the safe one of most similar attempted velocity: the field-keeping rule
of :func:`aibo_gym.explorer.shield_command`, applied in training too), ``margin_mm``. Its observation is
:meth:`OnboardTracker.features` (onboard only). SB3 is imported only when this policy is built;
a missing file or an agent for another observation or action space is one ValueError line.
"""

from __future__ import annotations

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


def load_agent(path: str):
    """(SB3 model, its metadata dict) of an agent file; ValueError naming the file otherwise."""
    if not os.path.isfile(path) and os.path.isfile(path + ".zip"):
        path = path + ".zip"
    if not os.path.isfile(path):
        raise ValueError(f"sb3 agent {path!r}: no such file (train one with 'aibo train-explorer')")
    meta: dict[str, Any] = {}
    side = sidecar_path(path)
    if os.path.isfile(side):
        try:
            with open(side) as f:
                meta = json.load(f)
        except (OSError, ValueError) as exc:
            raise ValueError(f"sb3 agent {side!r}: unreadable metadata ({exc})") from None
    if meta.get("features", FEATURES_VERSION) != FEATURES_VERSION:
        raise ValueError(f"sb3 agent {path!r}: trained on observation '{meta.get('features')}', this version builds "
                         f"'{FEATURES_VERSION}' (retrain it)")
    try:
        import stable_baselines3 as sb3
    except ImportError:
        raise ValueError("policy 'sb3' needs Stable-Baselines3 (pip install -e '.[agents]')") from None
    algos = [meta["algo"]] if meta.get("algo") in ALGOS else list(ALGOS)
    model, errors = None, []
    for algo in algos:
        try:
            model = getattr(sb3, algo.upper()).load(path, device="cpu")
            break
        except Exception as exc:  # noqa: BLE001 - any failure to read it is reported in one line
            errors.append(f"{algo}: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}")
    if model is None:
        raise ValueError(f"sb3 agent {path!r}: not a readable SB3 agent ({'; '.join(errors)})")
    obs_shape = tuple(getattr(model.observation_space, "shape", ()) or ())
    n_act = getattr(model.action_space, "n", None)
    if obs_shape != (N_FEATURES,) or n_act != N_ACTIONS:
        raise ValueError(f"sb3 agent {path!r}: observation {obs_shape} and {n_act} actions do not match this explorer's "
                         f"({N_FEATURES},) onboard features and {N_ACTIONS} commands (an agent for another env?)")
    return model, meta


@register_policy
class SB3Policy(HoldPolicy):
    name = "sb3"
    defaults = {"path": "", "hold_s": None, "margin_mm": 300.0, "deterministic": True, "shield": True}

    def __init__(self, config, seed=None, **params) -> None:
        super().__init__(config, seed=seed, **params)
        self.model, self.meta = load_agent(self.params["path"])
        if self.params["hold_s"] is None:
            self.set_hold(float(self.meta.get("hold_s", 5.0)))
        self.max_steps = int(self.meta.get("episode_steps", self.cfg["max_steps"]))

    def choose(self) -> int:
        obs = self.tracker.features(self.max_steps)
        action, _ = self.model.predict(obs, deterministic=self.params["deterministic"])
        a = int(np.asarray(action).reshape(-1)[0])
        if not self.params["shield"]:
            return a
        from ..explorer import shield_command

        return shield_command(self.tracker, a, self.hold_s, self.margin)
