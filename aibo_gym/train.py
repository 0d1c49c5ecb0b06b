"""Training an SB3 explorer (``aibo train-explorer``): PPO or DQN on :class:`~aibo_gym.explorer.HoldWrapper`.

Stable-Baselines3 and torch are imported only here. The agent is written to
``AGENT.zip`` with ``AGENT.json`` beside it, the pair all or nothing (algorithm, hold, the observation's version, the
training config), which the ``sb3`` policy reads.
"""

from __future__ import annotations

import hashlib
import importlib.util
import io
import json
import os
from pathlib import Path
from typing import Any

from aibo_core.atomic import atomic_write_all

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


#: The learned ``explorer``'s training: PPO fine-tuning (after the greedy warm start) with a small
#: learning rate and no entropy bonus, so that it departs from ``greedy`` only where the reward says so.
INFO_PPO = {"n_steps": 1024, "batch_size": 128, "n_epochs": 5, "gamma": 0.95, "ent_coef": 0.0, "learning_rate": 1e-4}
#: The shipped agent's training (``aibo train-explorer`` with its defaults): PPO holds, greedy holds imitated.
EXPLORER_STEPS = 60000
EXPLORER_WARM_HOLDS = 1800
WARM_EPOCHS = 30  # passes of the warm start over the greedy rollouts
WARM_BATCH = 256


def _save(model, out: Path, meta: dict[str, Any]) -> None:
    """Write the agent to ``out`` and its metadata (with the agent's SHA-256, ``agent_sha256``) to ``out``'s
    ``.json``, all or nothing (``atomic_write_all``): a failure leaves the old pair as it was."""
    buffer = io.BytesIO()
    model.save(buffer)
    data = buffer.getvalue()
    text = json.dumps({**meta, "agent_sha256": hashlib.sha256(data).hexdigest()}, indent=1)
    atomic_write_all([(out, lambda f: f.write(data)), (out.with_suffix(".json"), lambda f: f.write(text.encode()))])


def teacher_rollouts(env, holds: int, gamma: float) -> tuple[Any, Any, Any]:
    """(observations, ``greedy``'s actions, discounted returns) of ``holds`` steps of ``greedy`` in the
    :class:`~aibo_gym.explorer.InfoExplorerEnv` ``env`` (already seeded), episodes back to back."""
    import numpy as np

    from .policies.explorer import teacher_action

    obs_l, act_l, ret_l = [], [], []
    obs, _ = env.reset()
    ep_obs, ep_act, ep_rew = [], [], []
    for i in range(holds):
        a = teacher_action(obs)
        ep_obs.append(obs)
        ep_act.append(a)
        obs, r, term, trunc, _ = env.step(a)
        ep_rew.append(r)
        if term or trunc or i == holds - 1:
            g, ret = 0.0, []
            for r in reversed(ep_rew):
                g = r + gamma * g
                ret.append(g)
            obs_l += ep_obs
            act_l += ep_act
            ret_l += ret[::-1]
            ep_obs, ep_act, ep_rew = [], [], []
            obs, _ = env.reset()
    return np.asarray(obs_l, np.float32), np.asarray(act_l), np.asarray(ret_l, np.float32)


def warm_start(model, obs, actions, returns, seed: int, epochs: int = WARM_EPOCHS) -> float:
    """Fit the PPO policy to the teacher's actions (cross-entropy) and its value to the returns (MSE)
    with the model's optimizer, minibatches in a seeded order; the last epoch's mean loss."""
    import numpy as np
    import torch

    pol = model.policy
    rng = np.random.default_rng(seed)
    o, a, r = (torch.as_tensor(x) for x in (obs, actions, returns))
    loss_mean = float("nan")
    for _ in range(epochs):
        perm = rng.permutation(len(o))
        losses = []
        for i in range(0, len(o), WARM_BATCH):
            idx = torch.as_tensor(perm[i:i + WARM_BATCH])
            values, logp, _ = pol.evaluate_actions(o[idx], a[idx])
            loss = -logp.mean() + 0.5 * torch.nn.functional.mse_loss(values.flatten(), r[idx])
            pol.optimizer.zero_grad()
            loss.backward()
            pol.optimizer.step()
            losses.append(loss.item())
        loss_mean = float(np.mean(losses))
    return loss_mean


def train_info_explorer(steps: int, seed: int, out: str | os.PathLike, config: dict[str, Any] | None = None,
                        hold_s: float = 5.0, episode_minutes: float = 15.0, warm_holds: int = EXPLORER_WARM_HOLDS,
                        progress: bool = True) -> dict[str, Any]:
    """Train the ``explorer`` policy's agent: ``warm_holds`` holds of ``greedy`` imitated (the warm
    start), then PPO for ``steps`` holds on :class:`~aibo_gym.explorer.InfoExplorerEnv` (robots
    resampled every episode, reward the increase of the onboard log det), one env, one thread; write
    ``out`` and its ``.json``; return the metadata."""
    import stable_baselines3 as sb3
    import torch
    from stable_baselines3.common.vec_env import DummyVecEnv

    from .explorer import TRAIN_ROBOT_SEEDS, InfoExplorerEnv
    from .policies.explorer import INFO_FEATURES, N_INFO_FEATURES

    out = _check_out(out)
    torch.set_num_threads(1)
    torch.manual_seed(seed)
    cfg = dict(config or {})
    make = lambda: InfoExplorerEnv(cfg, hold_s=hold_s, episode_minutes=episode_minutes)  # noqa: E731
    teacher_env = make()
    teacher_env.reset(seed=seed + 1)
    vec = DummyVecEnv([make])
    vec.seed(seed)
    from .policies.explorer_net import PerCommandPolicy

    n_steps = min(INFO_PPO["n_steps"], max(steps, 2))  # a smoke run need not collect a full rollout
    kwargs = {**INFO_PPO, "n_steps": n_steps, "batch_size": min(INFO_PPO["batch_size"], n_steps)}
    model = sb3.PPO(PerCommandPolicy, vec, seed=seed, verbose=0, device="cpu", **kwargs)
    warm_loss = None
    if warm_holds > 0:
        data = teacher_rollouts(teacher_env, warm_holds, INFO_PPO["gamma"])
        warm_loss = warm_start(model, *data, seed=seed)
    if steps > 0:
        _no_log_folder(model)
        model.learn(total_timesteps=steps, callback=_progress_callback(steps) if progress else None)
    vec.close()
    meta = {"format": "aibo-explorer/1", "policy": "explorer", "algo": "ppo", "hold_s": float(hold_s),
            "features": INFO_FEATURES, "n_features": N_INFO_FEATURES, "episode_minutes": float(episode_minutes),
            "steps": int(steps), "warm_holds": int(warm_holds), "warm_loss": warm_loss, "seed": int(seed),
            "n_envs": 1, "config": cfg, "algo_kwargs": kwargs, "robot_seeds": list(TRAIN_ROBOT_SEEDS)}
    _save(model, out, meta)
    return meta


def _no_log_folder(model) -> None:
    """A logger that writes nothing: without one, SB3's ``learn`` makes an empty folder ``SB3-<time>`` in the
    system's temporary directory on every call (``configure_logger`` with no TensorBoard folder), which is
    never removed."""
    from stable_baselines3.common.logger import Logger

    model.set_logger(Logger(folder=None, output_formats=[]))


def _check_out(out: str | os.PathLike) -> Path:
    out = Path(out)
    if out.suffix != ".zip":
        raise ValueError(f"--out {str(out)!r}: the agent file must end in .zip")
    return out


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
    out = _check_out(out)
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
    if tb is None:
        _no_log_folder(model)
    try:
        model.learn(total_timesteps=steps, callback=_progress_callback(steps) if progress else None)
    finally:
        vec.close()
    meta = {"format": "aibo-explorer/1", "algo": algo, "hold_s": float(hold_s), "features": FEATURES_VERSION,
            "n_features": N_FEATURES, "episode_steps": int(full["max_steps"]), "steps": int(steps), "seed": int(seed),
            "n_envs": int(n_envs), "config": cfg, "algo_kwargs": kwargs, "tensorboard": tb}
    _save(model, out, meta)
    return meta
