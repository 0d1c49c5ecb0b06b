"""Training an SB3 explorer (``aibo train-explorer``): PPO or DQN on :class:`~aibo_gym.explorer.HoldWrapper`.

Stable-Baselines3 and torch are imported only here. The agent is written atomically to
``AGENT.zip`` with ``AGENT.json`` beside it (algorithm, hold, the observation's version, the
training config), which the ``sb3`` policy reads.
"""

from __future__ import annotations

import importlib.util
import json
import os
from pathlib import Path
from typing import Any

from aibo_core.atomic import atomic_write

from .policies.onboard import FEATURES_VERSION, N_FEATURES

#: Defaults of the training env config: 15-minute episodes, the exploration reward with the
#: per-frame terms scaled so that a hold's reward is of order 0.01-1.
TRAIN_CONFIG = {"reward": "explore", "reward_weights": {"balance": 10.0, "coverage": 10.0, "sightings": 0.0,
                                                        "wall": 0.01, "info_gain": 0.0}}
ALGO_DEFAULTS = {
    "ppo": {"n_steps": 256, "batch_size": 128, "n_epochs": 5, "gamma": 0.99, "ent_coef": 0.01, "learning_rate": 3e-4},
    "dqn": {"learning_starts": 500, "buffer_size": 50_000, "exploration_fraction": 0.3, "train_freq": 4,
            "target_update_interval": 1000, "gamma": 0.99, "learning_rate": 3e-4},
}


def _progress_callback(total: int):
    from stable_baselines3.common.callbacks import BaseCallback
    from tqdm import tqdm

    class TqdmCallback(BaseCallback):
        def _on_training_start(self) -> None:
            self.bar = tqdm(total=total, unit="step", desc="train-explorer")

        def _on_step(self) -> bool:
            self.bar.update(self.training_env.num_envs)
            return True

        def _on_training_end(self) -> None:
            self.bar.close()

    return TqdmCallback()


def train_explorer(algo: str, steps: int, seed: int, out: str | os.PathLike, config: dict[str, Any] | None = None,
                   hold_s: float = 5.0, n_envs: int = 2, subprocess: bool = True, tensorboard: str | None = None,
                   progress: bool = True, algo_kwargs: dict[str, Any] | None = None) -> dict[str, Any]:
    """Train and save the agent; return its metadata (also written to ``AGENT.json``)."""
    import stable_baselines3 as sb3
    import torch

    from .config import make_config
    from .explorer import make_explorer_vec_env

    if algo not in ALGO_DEFAULTS:
        raise ValueError(f"algo {algo!r} (valid choices: {', '.join(ALGO_DEFAULTS)})")
    out = Path(out)
    if out.suffix != ".zip":
        raise ValueError(f"--out {str(out)!r}: the agent file must end in .zip")
    user = dict(config or {})
    cfg = {**TRAIN_CONFIG, **user}
    if "reward_weights" in user:
        cfg["reward_weights"] = {**TRAIN_CONFIG["reward_weights"], **user["reward_weights"]}
    full = make_config(cfg)  # validate before starting workers
    torch.set_num_threads(1)
    vec = make_explorer_vec_env(cfg, n_envs, seed, hold_s, subprocess=subprocess)
    tb = None
    if tensorboard and importlib.util.find_spec("tensorboard") is not None:
        tb = str(tensorboard)
    kwargs = {**ALGO_DEFAULTS[algo], **(algo_kwargs or {})}
    if algo == "ppo":
        kwargs["batch_size"] = min(kwargs["batch_size"], kwargs["n_steps"] * n_envs)
    model = getattr(sb3, algo.upper())("MlpPolicy", vec, seed=seed, verbose=0, device="cpu", tensorboard_log=tb, **kwargs)
    try:
        model.learn(total_timesteps=steps, callback=_progress_callback(steps) if progress else None)
    finally:
        vec.close()
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.stem}-{os.getpid()}.tmp.zip")
    model.save(tmp)
    os.replace(tmp, out)
    meta = {"format": "aibo-explorer/1", "algo": algo, "hold_s": float(hold_s), "features": FEATURES_VERSION,
            "n_features": N_FEATURES, "episode_steps": int(full["max_steps"]), "steps": int(steps), "seed": int(seed),
            "n_envs": int(n_envs), "config": cfg, "algo_kwargs": kwargs, "tensorboard": tb}
    text = json.dumps(meta, indent=1)
    atomic_write(out.with_suffix(".json"), lambda f: f.write(text.encode()))
    return meta
