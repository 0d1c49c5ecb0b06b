"""``aibo collect``: run the simulator with an exploration policy and write a log; with ``--model``,
the simulator is calibrated to a fitted model, and with ``--replay`` it replays a measured log."""

from __future__ import annotations

import sys
import time

import numpy as np

from aibo.errors import CLIError
from aibo.paths import check_files, declared_inputs
from aibo_core import trajectory


def run(args) -> int:
    from aibo_gym.collect import collect, replay
    from aibo_gym.config import default_config

    check_files(inputs=declared_inputs(args), outputs=[("--out", args.out)] + ([("--plot", args.plot)] if args.plot else []))
    if args.replay and not args.model:
        raise CLIError("--replay needs --model (the model whose simulator replays the log)")
    model_config, log = calibrated_config(args.model, args.replay)
    # --steps frames, also past the default episode limit, unless --config sets max_steps
    config = {"max_steps": max(args.steps, default_config()["max_steps"]), **model_config, **args.config}
    if args.preset:
        config["noise"] = args.preset
    t0 = time.perf_counter()
    if log is not None:
        tr = replay(config, log.actions, args.seed, head_pan=log.head_pan, source=str(args.replay),
                    progress=sys.stderr.isatty())
    else:
        tr = collect(config, steps=args.steps, seed=args.seed, policy=args.policy, localizer=args.localizer,
                     progress=sys.stderr.isatty(), policy_params=args.policy_params)
    seconds = time.perf_counter() - t0
    if args.plot:
        from aibo_gym.plot import plot_trajectory

        plot_trajectory(tr, args.plot, title=f"{tr.n_frames} frames, seed {args.seed}")
    if args.blind:
        tr = trajectory.blind(tr)
    trajectory.save(tr, args.out)
    seen = (trajectory.sightings_per_frame(tr) > 0).mean()
    print(f"wrote {args.out}: {tr.n_frames} frames ({tr.n_frames * tr.dt / 60:.1f} min), "
          f"{seen:.0%} with a sighting, {tr.n_frames / seconds:,.0f} frames/s"
          + (f"; figure {args.plot}" if args.plot else ""))
    return 0


def calibrated_config(model_path: str | None, replay_path: str | None):
    """(env config of the model's simulator, the log to replay or None); ({}, None) without a model."""
    if not model_path:
        return {}, None
    from experiments.calibrated import simulator_config
    from learners.model.io import load_model

    model = load_model(model_path)
    log = trajectory.load(replay_path) if replay_path else None
    if log is not None and not np.isclose(log.dt, model.action.dt, rtol=1e-6):
        raise CLIError(f"--replay {replay_path}: field 'dt': {log.dt:g} s per frame, but the model {model_path} "
                       f"steps {model.action.dt:g} s per frame; replay a log of the model's frame rate")
    if log is not None and log.actions is None:
        raise CLIError(f"{replay_path}: field 'actions': the log has continuous commands; the simulator replays "
                       "only the 40 discrete walk commands")
    try:
        return simulator_config(model, log), log
    except ValueError as err:
        raise CLIError(f"{model_path}: {err}") from None
