"""``aibo experiment policies``: a sweep of exploration policies x log lengths x seeds (``experiments``)."""

from __future__ import annotations

import time
from pathlib import Path

from aibo.errors import CLIError


def _list(text: str, kind, what: str) -> list:
    try:
        out = [kind(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise CLIError(f"{what}: expected a comma-separated list, got {text!r}") from None
    if not out:
        raise CLIError(f"{what}: empty list")
    return out


#: The files a sweep writes into --out (besides runs/).
OUTPUTS = ("results.jsonl", "summary.json", "errors_vs_minutes.png")
FRAMES_PER_MINUTE = 30 * 60  # AiboBeacons-v0 steps at 30 Hz


def max_minutes() -> float:
    """Longest log of one run, training or held out (minutes): what ``aibo collect --steps`` may simulate
    (``aibo.options.max_steps``: 10^8 frames, or what half of this machine's memory holds)."""
    from aibo.options import max_steps

    return max_steps() / FRAMES_PER_MINUTE


def check_minutes(minutes: list[float], text: str, holdout: float) -> None:
    """Refuse (CLIError) a log length (``minutes`` parsed from ``text``; ``holdout``) no run could simulate
    (``--holdout-minutes`` 1e5 ran for hours, ~29 GB)."""
    limit = max_minutes()
    if any(not 0 < m <= limit for m in minutes):
        raise CLIError(f"--minutes {text}: every length must be a number of minutes in "
                       f"(0, {limit:,.0f}] (what aibo collect may simulate on this machine)")
    if holdout > limit:
        raise CLIError(f"--holdout-minutes {holdout:g}: at most {limit:,.0f} minutes (what aibo collect may simulate "
                       "on this machine)")


def validate_configs(specs) -> None:
    """Refuse (CLIError, one line) a sweep whose env config (``--config``) the simulator would refuse."""
    from aibo_gym.config import make_config

    for spec in specs:
        try:
            make_config(spec.env)
        except ValueError as err:
            raise CLIError(f"--config: {err}") from None


def run(args) -> int:
    from aibo.paths import check_files, declared_inputs
    from experiments import policies as sweep
    from experiments.executors import run_all

    out = Path(args.out)
    check_files(declared_inputs(args), [("--out file", out / name) for name in OUTPUTS], folders=[("--out", out)])
    minutes = _list(args.minutes, float, "--minutes")
    check_minutes(minutes, args.minutes, args.holdout_minutes)
    names = [n.strip() for n in args.policies.split(",") if n.strip()]
    if not names:
        raise CLIError("--policies: empty list")
    try:
        pols = sweep.policy_specs(names, args.policy_params)
    except ValueError as err:
        raise CLIError(f"--policy-params: {err}") from None
    learner = {} if args.max_iter is None else {"max_iter": args.max_iter}
    seeds = list(range(args.seed_base, args.seed_base + args.seeds))
    specs = sweep.build_specs(pols, sorted(minutes), seeds, args.config, args.robot_seed_base, learner,
                              args.holdout_minutes)
    validate_configs(specs)  # everything is checked before results.jsonl or summary.json is touched
    t0 = time.perf_counter()

    def on_record(rec, done, total):
        print(f"[{done}/{total}] {rec['policy']:>18s} {rec['minutes']:5g} min seed {rec['seed']:<3d} "
              f"vx {100 * rec['vx_rel']:.2f}% vy {100 * rec['vy_rel']:.2f}% vtheta {100 * rec['vth_rel']:.2f}% "
              f"sensor {rec['sensor_rms_px']:.3f} px, {rec['iterations']} it, {rec['timing']['total_s']:.0f} s",
              flush=True)

    print(f"{len(specs)} runs ({len(pols)} policies x {len(minutes)} lengths x {len(seeds)} seeds), backend "
          f"{args.backend}, results in {out}/results.jsonl", flush=True)
    records = run_all(specs, out, backend=args.backend, jobs=args.jobs, address=args.address, on_record=on_record)
    summary = sweep.write_summary(out, records)
    sweep.plot(summary, out / "errors_vs_minutes.png")
    print()
    print(sweep.table(summary))
    print()
    for line in sweep.verdict(summary):
        print(line)
    print(f"wrote {out}/results.jsonl ({len(records)} runs), summary.json, errors_vs_minutes.png "
          f"in {time.perf_counter() - t0:.0f} s")
    return 0
