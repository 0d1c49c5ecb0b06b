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


def run(args) -> int:
    from aibo.paths import check_files
    from experiments import policies as sweep
    from experiments.executors import run_all

    out = Path(args.out)
    check_files([], [], folders=[("--out", out)])
    minutes = _list(args.minutes, float, "--minutes")
    if any(not m > 0 for m in minutes):
        raise CLIError(f"--minutes: every length must be > 0, got {args.minutes}")
    names = [n.strip() for n in args.policies.split(",") if n.strip()]
    if not names:
        raise CLIError("--policies: empty list")
    pols = sweep.policy_specs(names, args.policy_params)
    learner = {} if args.max_iter is None else {"max_iter": args.max_iter}
    seeds = list(range(args.seed_base, args.seed_base + args.seeds))
    specs = sweep.build_specs(pols, sorted(minutes), seeds, args.config, args.robot_seed_base, learner,
                              args.holdout_minutes)
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
