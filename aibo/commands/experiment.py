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


def check_backend(args) -> None:
    """Refuse (CLIError) options the chosen --backend would ignore, and Ray when it is not installed."""
    import importlib.util

    if args.address is not None and args.backend != "ray":
        raise CLIError(f"--address {args.address}: only --backend ray connects to a cluster (got --backend "
                       f"{args.backend}); drop --address or give --backend ray")
    if args.jobs is not None and args.jobs != 1 and args.backend == "serial":
        raise CLIError(f"--jobs {args.jobs}: --backend serial does one run at a time; drop --jobs or give --backend "
                       "pool")
    if args.backend == "ray" and importlib.util.find_spec("ray") is None:
        raise CLIError("--backend ray: Ray is not installed (pip install -e '.[ray]'); or give --backend pool")


def check_once(values: list, text: str, option: str) -> None:
    """Refuse (CLIError) a value given twice in a list option (``text`` as given): its runs would repeat."""
    for i, v in enumerate(values):
        if v in values[:i]:
            shown = f"{v:g}" if isinstance(v, float) else repr(v)
            raise CLIError(f"{option} {text}: {shown} is given twice; give each once (its runs would repeat)")


def policies(args) -> list[dict]:
    """The validated policy specs of --policies with --policy-params: a bad name names --policies, a bad
    parameter or a parameter group of no policy in --policies names --policy-params."""
    from aibo_gym.policies import policy_label, validate_policy
    from experiments import policies as sweep

    names = [n.strip() for n in args.policies.split(",") if n.strip()]
    if not names:
        raise CLIError("--policies: empty list")
    labels = []
    for name in names:
        try:
            labels.append(policy_label(validate_policy(name)))
        except ValueError as err:
            raise CLIError(f"--policies: {err}") from None
    check_once(labels, args.policies, "--policies")
    params = args.policy_params or {}
    for key in params:
        if key not in names and key not in labels:
            raise CLIError(f"--policy-params: {key!r} is not one of --policies ({', '.join(names)}); give "
                           "{policy: {param: value}} for the policies of the sweep")
    try:
        return sweep.policy_specs(names, params)
    except ValueError as err:
        raise CLIError(f"--policy-params: {err}") from None


#: Most sightings one AiboBeacons-v0 frame holds: its camera reports the beacon nearest the image centre
#: (``aibo_gym.camera``), and the spurious-sightings effect joins a real sighting with at most one spurious one.
MAX_SIGHTINGS_PER_FRAME = 2


def min_run_frames() -> tuple[int, int]:
    """(frames, sightings): the fewest sightings any fit needs (``learners.em.support``: a number per parameter of
    the smallest sensor model EM starts from) and the fewest frames that can hold them; a shorter log cannot be
    fitted, whatever its luck."""
    from learners.em.options import DEFAULT_DEGREE
    from learners.em.support import MIN_SIGHTINGS_PER_PARAMETER

    need = MIN_SIGHTINGS_PER_PARAMETER * (min(DEFAULT_DEGREE.values()) + 1 + 2)  # curve coefficients and two sds
    return -(-need // MAX_SIGHTINGS_PER_FRAME), need


def check_run_lengths(minutes: list[float], text: str, config: dict, max_steps: int) -> None:
    """Refuse (CLIError) a run whose log (--minutes, or --config's ``max_steps`` ending every episode; ``max_steps``:
    the env's, validated) is too short for any fit (``min_run_frames``): it failed in the sweep's first run, naming
    neither option."""
    from experiments.run import RunSpec

    least, need = min_run_frames()
    why = (f"a fit needs at least {need} sightings and a frame holds at most {MAX_SIGHTINGS_PER_FRAME}: at least "
           f"{least} frames ({least / FRAMES_PER_MINUTE:.2g} min)")
    for m in minutes:
        frames = RunSpec("uniform", m, 0).steps
        if frames < least:
            raise CLIError(f"--minutes {text}: a run of {m:g} min is {frames} frame(s); {why}")
    if "max_steps" in config and max_steps < least:
        raise CLIError(f"--config: 'max_steps' {max_steps} ends every run's log at {max_steps} frame(s); {why}")


def run(args) -> int:
    from aibo.paths import check_files, declared_inputs
    from aibo_gym.config import make_config
    from experiments import policies as sweep
    from experiments.executors import run_all

    out = Path(args.out)
    check_files(declared_inputs(args), [("--out file", out / name) for name in OUTPUTS], folders=[("--out", out)])
    # everything is checked before --out, results.jsonl or summary.json is touched
    check_backend(args)
    minutes = _list(args.minutes, float, "--minutes")
    check_minutes(minutes, args.minutes, args.holdout_minutes)
    check_once(minutes, args.minutes, "--minutes")
    pols = policies(args)
    learner = {} if args.max_iter is None else {"max_iter": args.max_iter}
    seeds = list(range(args.seed_base, args.seed_base + args.seeds))
    specs = sweep.build_specs(pols, sorted(minutes), seeds, args.config, args.robot_seed_base, learner,
                              args.holdout_minutes)
    validate_configs(specs)
    env = make_config(specs[0].env)
    for pol in pols:
        try:
            sweep.check_params(pol, env["field"])
        except ValueError as err:
            raise CLIError(f"--policy-params: {err}") from None
    check_run_lengths(minutes, args.minutes, args.config, env["max_steps"])
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
