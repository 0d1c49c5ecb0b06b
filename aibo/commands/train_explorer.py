"""``aibo train-explorer``: train an SB3 agent (PPO or DQN) whose step is one command hold."""

from __future__ import annotations

import importlib.util
import json
import sys
import time

from aibo.errors import CLIError


def run(args) -> int:
    from aibo.paths import check_files, declared_inputs

    if importlib.util.find_spec("stable_baselines3") is None:
        from aibo_gym.policies.sb3 import AGENTS_HINT

        raise CLIError(f"train-explorer needs Stable-Baselines3: {AGENTS_HINT}")
    check_files(declared_inputs(args), [("--out", args.out), ("--out's description", args.out[:-4] + ".json")])
    t0 = time.perf_counter()
    meta = _train_explorer(args) if args.policy == "explorer" else _train_sb3(args)
    spec = f"explorer --policy-params '{json.dumps({'path': args.out})}'" if args.policy == "explorer" else f"sb3:{args.out}"
    print(f"wrote {args.out} ({meta['algo']}, {meta['steps']} holds of {meta['hold_s']:g} s, {meta['n_envs']} envs) and "
          f"{args.out[:-4]}.json in {time.perf_counter() - t0:.0f} s; collect with --policy {spec}")
    return 0


def _train_explorer(args) -> dict:
    from aibo_gym.train import EXPLORER_STEPS, EXPLORER_WARM_HOLDS, train_info_explorer

    if args.algo not in (None, "ppo"):
        raise CLIError(f"--algo {args.algo}: the explorer policy's agent is PPO (use --policy sb3 for DQN)")
    steps = EXPLORER_STEPS if args.steps is None else args.steps
    warm = EXPLORER_WARM_HOLDS if args.warm_holds is None else args.warm_holds
    return train_info_explorer(steps, args.seed, args.out, args.config, args.hold_s, args.episode_minutes, warm,
                               progress=sys.stderr.isatty())


def _train_sb3(args) -> dict:
    from aibo_gym.train import train_explorer

    if args.tensorboard and importlib.util.find_spec("tensorboard") is None:
        print("aibo: tensorboard is not installed: no TensorBoard logs", file=sys.stderr)
    return train_explorer(args.algo or "ppo", 20000 if args.steps is None else args.steps, args.seed, args.out, args.config,
                          args.hold_s, args.n_envs, subprocess=args.vec == "subproc", tensorboard=args.tensorboard,
                          progress=sys.stderr.isatty())
