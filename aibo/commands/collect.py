"""``aibo collect``: run the simulator with an exploration policy and write a log."""

from __future__ import annotations

import sys
import time

from aibo.paths import check_files
from aibo_core import trajectory


def run(args) -> int:
    from aibo_gym.collect import collect
    from aibo_gym.config import default_config

    check_files(inputs=[], outputs=[("--out", args.out)] + ([("--plot", args.plot)] if args.plot else []))
    # --steps frames, also past the default episode limit, unless --config sets max_steps
    config = {"max_steps": max(args.steps, default_config()["max_steps"]), **args.config}
    if args.preset:
        config["noise"] = args.preset
    t0 = time.perf_counter()
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
