"""``aibo train-explorer``: train an SB3 agent (PPO or DQN) whose step is one command hold."""

from __future__ import annotations

import importlib.util
import sys
import time

from aibo.errors import CLIError


def run(args) -> int:
    from aibo.paths import check_files, declared_inputs

    if importlib.util.find_spec("stable_baselines3") is None:
        raise CLIError("train-explorer needs Stable-Baselines3: pip install -e '.[agents]' "
                       "(CPU torch first, see docs/environments.md)")
    check_files(declared_inputs(args), [("--out", args.out), ("--out's description", args.out[:-4] + ".json")])
    from aibo_gym.train import train_explorer

    if args.tensorboard and importlib.util.find_spec("tensorboard") is None:
        print("aibo: tensorboard is not installed: no TensorBoard logs", file=sys.stderr)
    t0 = time.perf_counter()
    meta = train_explorer(args.algo, args.steps, args.seed, args.out, args.config, args.hold_s, args.n_envs,
                          subprocess=args.vec == "subproc", tensorboard=args.tensorboard, progress=sys.stderr.isatty())
    print(f"wrote {args.out} ({args.algo}, {args.steps} holds of {meta['hold_s']:g} s, {args.n_envs} envs) and "
          f"{args.out[:-4]}.json in {time.perf_counter() - t0:.0f} s; collect with --policy sb3:{args.out}")
    return 0
