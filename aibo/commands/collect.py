"""``aibo collect``: run the simulator with an exploration policy and write a log; with ``--model``,
the simulator is calibrated to a fitted model, and with ``--replay`` it replays a measured log.

Two simulators (``--env``): ``AiboBeacons-v0`` (``aibo``: 40 discrete walk commands, a height camera)
and ``WheeledRobot-v0`` (``wheeled``: continuous (v, omega) commands, a range/bearing camera, driven
to random waypoints). A model with continuous commands is simulated by the wheeled env."""

from __future__ import annotations

import sys
import time

import numpy as np

from aibo.errors import CLIError
from aibo.paths import check_files, declared_inputs
from aibo_core import trajectory

DEFAULT_STEPS = {"aibo": 27000, "wheeled": 6000}


def run(args) -> int:
    check_files(inputs=declared_inputs(args), outputs=[("--out", args.out)] + ([("--plot", args.plot)] if args.plot else []))
    if args.replay and not args.model:
        raise CLIError("--replay needs --model (the model whose simulator replays the log)")
    if args.preset and args.model:
        raise CLIError(f"--preset {args.preset}: not with --model, whose fitted sensor noise the simulator takes (the "
                       "log would name a preset it did not use); drop --preset, or --model for a preset's noise")
    model_config, log, env = calibrated_config(args.model, args.replay, args.env)
    steps = args.steps or DEFAULT_STEPS[env]
    t0 = time.perf_counter()
    tr = (run_wheeled if env == "wheeled" else run_aibo)(args, model_config, log, steps)
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


def run_aibo(args, model_config: dict, log, steps: int):
    """The log of ``AiboBeacons-v0``: collected with ``--policy`` or replaying ``log``'s commands."""
    from aibo_gym.collect import collect, replay
    from aibo_gym.config import default_config

    # --steps frames, also past the default episode limit, unless --config sets max_steps
    config = {"max_steps": max(steps, default_config()["max_steps"]), **model_config, **args.config}
    if args.preset:
        config["noise"] = args.preset
    if log is not None:
        return replay(config, log.actions, args.seed, head_pan=log.head_pan, source=str(args.replay),
                      progress=sys.stderr.isatty())
    check_policy(args, config)
    return collect(config, steps=steps, seed=args.seed, policy=args.policy or "random-balanced",
                   localizer=args.localizer, progress=sys.stderr.isatty(), policy_params=args.policy_params)


def check_policy(args, config: dict) -> None:
    """Refuse (CLIError naming --policy-params) policy parameters no run could use in the env ``config``
    (``experiments.policies.check_params``), before the simulation. A bad config, policy name or parameter is
    left to ``collect``, which says it as always."""
    from aibo_gym.collect import policy_spec
    from aibo_gym.config import make_config
    from experiments.policies import check_params

    try:
        field = make_config(config)["field"]
        spec = policy_spec(args.policy or "random-balanced", args.localizer, args.policy_params)
    except ValueError:
        return
    try:
        check_params(spec, field)
    except ValueError as err:
        raise CLIError(f"--policy-params: {err}") from None


def run_wheeled(args, model_config: dict, log, steps: int):
    """The log of ``WheeledRobot-v0``: driven to random waypoints or replaying ``log``'s controls."""
    from aibo_gym.collect_wheeled import collect_wheeled, replay_wheeled
    from aibo_gym.wheeled_config import default_config
    from experiments.calibrated_wheeled import image_frames

    for flag, value, ok in (("--policy", args.policy, (None, "waypoints")), ("--localizer", args.localizer, (None,)),
                            ("--preset", args.preset, (None,))):
        if value not in ok:
            raise CLIError(f"{flag} {value}: not available with the wheeled simulator (it drives to random waypoints "
                           "on its true pose; its sensor noise is config 'sigma_range_mm' and 'sigma_bearing')")
    config = {"max_steps": max(steps, default_config()["max_steps"]), **model_config, **args.config}
    try:
        if log is not None:
            return replay_wheeled(config, log.controls, args.seed, images=image_frames(log), source=str(args.replay))
        return collect_wheeled(config, steps, args.seed, policy_params=args.policy_params)
    except ValueError as err:
        raise CLIError(str(err)) from None


def calibrated_config(model_path: str | None, replay_path: str | None, env: str | None = None):
    """(env config of the model's simulator, the log to replay or None, the env: "aibo" or "wheeled");
    ({}, None, ``env`` or "aibo") without a model."""
    if not model_path:
        return {}, None, env or "aibo"
    from experiments.calibrated import simulator_config
    from learners.model.io import load_model

    model = load_model(model_path)
    own = "aibo" if model.action.discrete else "wheeled"
    if env is not None and env != own:
        raise CLIError(f"--env {env}: {model_path} is a model of the {own} simulator (its action model is "
                       f"'{model.action.feature_map}')")
    log = trajectory.load(replay_path) if replay_path else None
    if log is not None and not np.isclose(log.dt, model.action.dt, rtol=1e-6):
        raise CLIError(f"--replay {replay_path}: field 'dt': {log.dt:g} s per frame, but the model {model_path} "
                       f"steps {model.action.dt:g} s per frame; replay a log of the model's frame rate")
    if log is not None and log.discrete != model.action.discrete:
        have, want = ("discrete", "continuous") if log.discrete else ("continuous", "discrete")
        raise CLIError(f"{replay_path}: field '{'actions' if log.discrete else 'controls'}': the log has {have} "
                       f"commands; the model {model_path} takes {want} ones")
    try:
        from experiments.calibrated import camera_paths

        path = camera_paths(model, [log])[0] if log is not None else None  # where its camera is measured
        return simulator_config(model, log, path=path), log, own
    except ValueError as err:
        raise CLIError(f"{model_path}: {err}") from None
