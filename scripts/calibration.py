"""Calibration of `aibo diagnose`'s estimates: do the named effects' 95% intervals cover the truth, is the estimate biased?

    python scripts/calibration.py [--logs 100] [--effects a,b,...] [--minutes 5] [--first-log 0] [--presets aibo,paper-sim]
                                  [--out runs/calibration]
    python scripts/calibration.py --out runs/calibration --table      # print the table of the rows so far
    python scripts/calibration.py --effects actuation_lag --strength actuation_lag.lag_s=0.15 --out runs/calibration-lag15
    python scripts/calibration.py --effects floor_drift --restricted-noise --out runs/calibration-reml

For each effect of the catalogue at one strength (``STRENGTH``) and each log i = ``--first-log`` .. ``--logs`` - 1:
a 5-minute blind log simulated with the effect (``aibo_gym.collect.collect``, seed ``SEED + i``, noise preset
``PRESETS[i % 2]``: ``aibo``, ``paper-sim`` alternating; for an effect of continuous commands, ``response_time``, a
wheeled robot's log, ``aibo_gym.collect_wheeled.collect_wheeled``, "preset" ``wheeled``), then what `aibo diagnose
LOG --candidates EFFECT` does to name it and to estimate it, in this process: the search
(``learners.discrepancy.search.search``, one candidate, one worker, diagnose's options) and, the effect named, the
final fit on the whole log with each named parameter's 95% interval (``learners.discrepancy.final.diagnosed``, the
function ``aibo diagnose`` calls; Wald with the robust standard errors (``--fisher`` tabulates the Fisher ones kept
beside them), the profile or conditional likelihood interval where Wald fails, the search's grid profile for the lag).
What the study skips of the command (the scores, signatures, motion gaps, the calibrated check, the page) does not
change the named effects or their intervals. Every random choice is the log's seed or diagnose's ``--seed 0``.

One row per (effect, log) in OUT/rows.jsonl, written after each log (the study resumes where it stopped); a second
process started with ``--first-log N`` writes OUT/rows-from-N.jsonl and skips the logs any rows file holds, and the
table reads every OUT/rows*.jsonl. OUT/table.md, printed at the end: per parameter (array parameters
per component) and noise preset, over the logs where the effect was named:

- coverage: the share of the 95% intervals that hold the truth, with its binomial standard error;
- bias: mean estimate - truth; SE: the mean of the reported standard errors (a grid or profile interval has none:
  its half-width / 1.96 stands in); bias / SE with its Monte Carlo standard error (the spread of estimate - truth
  over the logs / sqrt(n) / SE); spread / SE: the spread of the estimates over the logs against the mean reported
  standard error (1 when the standard errors are right);
- missing: named logs whose interval is None;
- not warned: the coverage over the named logs whose report gives no warning about the effect's values (no interval,
  moved since named, short of the likelihood's maximum: ``effect_sizes.read_with_care``, what `aibo diagnose` prints),
  and how many of the intervals that miss the truth come with such a warning.

``--presets paper-sim`` runs only the logs of that preset (odd i), e.g. to rerun one preset's shortfall.

``--restricted-noise``: the final fit with ``EMOptions.restricted_noise`` (``aibo diagnose --restricted-noise``: the
motion noise at the restricted likelihood's maximum, ``learners.em.restricted``); each row says which it was.

``--maximum-likelihood-variances``: the effects' variance parameters (``EffectModel.VARIANCE_PARAMS``) left at the
likelihood's maximum (``EMOptions.restricted_variances`` off; the rows before it existed were so); each row says which.

``--strength EFFECT.PARAM=VALUE`` (repeatable; VALUE a number or a JSON list) simulates an effect at another strength
than ``STRENGTH``'s, e.g. a lag between the grid's values; its rows go to their own ``--out`` (a folder holding rows of
the effect at another strength is refused: the table pools an effect's rows).

Targets (issue 34): coverage 90-98%, |bias| / SE < 1/3. Truths are compared in the learner's parametrization:
``beacon_height_scale`` normalized to geometric mean 1 and ``landmark_bearing_offset`` to mean 0 (their constraints).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):  # one BLAS thread, as the command (aibo/__init__.py)
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

from aibo_core.atomic import atomic_write, read_jsonl  # noqa: E402

#: The strength of each effect: the "medium" of ``scripts/diagnose_power.py``'s STRENGTHS, except where issue 34 asks
#: for another (``false_sightings`` at 8%) or where the medium is named on at most 1 in 10 five-minute `aibo` logs
#: (``floor_drift`` 6 mm/s, ``velocity_fade`` 0.01/min: 1 and 0 of 10): there the strong one (7 and 5 of 10), so that
#: the intervals given that the effect is named are not mostly a selection of lucky logs. ``wall_contact`` has no
#: parameter; ``angle_bias`` is not identifiable (never named: its right answer is none).
STRENGTH: dict[str, dict[str, Any]] = {
    "landmark_bias": {"sigma_rel": 0.05, "tau_s": 8.0},
    "landmark_bearing_bias": {"sigma_rad": 0.02, "tau_s": 20.0},
    "false_sightings": {"rate": 0.08},
    "off_center_shrink": {"k": 0.1},
    "actuation_lag": {"lag_s": 0.1},
    "beacon_height_scale": {"scale": [1.02, 0.98, 1.01, 0.99]},
    "distance_dependent_noise": {"exponent": 0.5},
    "landmark_bearing_offset": {"offset_rad": [0.01, -0.01, 0.005, -0.005]},
    "floor_drift": {"drift_mm_s": [12.0, 0.0]},
    "velocity_fade": {"fade_per_min": 0.02},
    "heavy_tailed_noise": {"rate": 0.1, "scale": 2.0},
    "response_time": {"tau_s": 0.15},  # continuous commands only: a wheeled robot's logs (WHEELED)
    "turn_dependent_noise": {"gain_s": 1.5},
    "turn_heading_noise": {"gain_s": 1.5},
}
PRESETS = ("aibo", "paper-sim")
#: the "preset" of the logs of an effect that needs continuous commands (``EffectModel.NEEDS``): ``WheeledRobot-v0``
#: driven to random waypoints from a random start (``collect_wheeled``), its default noise, 10 frames per second
WHEELED = "wheeled"
SEED = 8000  # log i has seed SEED + i (the power study's logs are 1000-5009)
Z95 = 1.959963984540054


def truth(effect: str, params: dict[str, Any], dt: float | None = None) -> dict[str, Any]:
    """The simulated parameters in the learner's parametrization (module docstring). ``dt``: the frame (s) of a log of
    discrete commands, where a lag acts in whole frames (``ActuationLag``: ceil(lag_s / dt) frames, in the simulator
    and the learner alike), so every lag in ((n - 1) dt, n dt] is the same model as n dt: that is the truth."""
    out = {k: (np.asarray(v, float) if np.ndim(v) else float(v)) for k, v in params.items()}
    if effect == "actuation_lag" and dt is not None:
        out["lag_s"] = math.ceil(out["lag_s"] / dt - 1e-9) * dt
    if effect == "beacon_height_scale":
        out["scale"] = out["scale"] / np.exp(np.mean(np.log(out["scale"])))
    if effect == "landmark_bearing_offset":
        out["offset_rad"] = out["offset_rad"] - np.mean(out["offset_rad"])
    return {k: np.asarray(v).tolist() for k, v in out.items()}


def set_strength(items: list[str]) -> None:
    """Apply ``--strength EFFECT.PARAM=VALUE`` items to ``STRENGTH`` (module docstring); ValueError naming the item."""
    import json

    for item in items:
        key, sep, value = item.partition("=")
        effect, dot, pname = key.partition(".")
        if not (sep and dot) or effect not in STRENGTH or pname not in STRENGTH[effect]:
            raise ValueError(f"--strength {item!r}: expected EFFECT.PARAM=VALUE with a parameter of "
                             f"{', '.join(f'{e}.{p}' for e in STRENGTH for p in STRENGTH[e])}")
        try:
            STRENGTH[effect] = {**STRENGTH[effect], pname: json.loads(value)}
        except json.JSONDecodeError:
            raise ValueError(f"--strength {item!r}: VALUE must be a number or a JSON list") from None


def wheeled(effect: str) -> bool:
    """Whether ``effect``'s logs are a wheeled robot's (it needs continuous commands: ``EffectModel.NEEDS``)."""
    from learners.model.effects import EFFECT_MODELS

    return "controls" in EFFECT_MODELS[effect].NEEDS


def one(effect: str, i: int, minutes: float, restricted: bool = False, variances: bool = True) -> dict[str, Any]:
    """Log ``i`` of ``effect``: simulated, searched and, the effect named, its final estimates and intervals."""
    from aibo_core.trajectory import blind
    from aibo_gym.collect import collect
    from aibo_gym.collect_wheeled import collect_wheeled
    from learners.discrepancy.final import plausible_diagnosis
    from learners.discrepancy.search import search
    from learners.em.options import EMOptions

    params, seed, preset = STRENGTH[effect], SEED + i, PRESETS[i % len(PRESETS)]
    if wheeled(effect):
        preset = WHEELED
        tr = collect_wheeled({"effects": {effect: params}, "start_pose": "random"}, int(round(minutes * 600)), seed)
    else:
        tr = blind(collect({"noise": preset, "effects": {effect: params}}, int(round(minutes * 60 * 30)), seed=seed))
    t0, c0 = time.perf_counter(), time.process_time()
    # ``aibo diagnose``'s (its --seed 0)
    opts = EMOptions(seed=0, lag_search=False, restricted_noise=restricted, restricted_variances=variances)
    found = search([tr], [effect], opts, jobs=1, progress=lambda s: None)
    tried = [c for rnd in found["rounds"] for c in rnd if c.name == effect]
    row = {"effect": effect, "log": i, "seed": seed, "preset": preset, "minutes": minutes, "params": params,
           "truth": truth(effect, params, None if preset == WHEELED else tr.dt), "named": [c.name for c in found["named"]],
           "restricted_noise": restricted, "restricted_variances": variances,
           "candidate": tried[0].as_dict() if tried else None, "n_sightings": int(sum(t.n_sightings for t in found["logs"])),
           "outliers": int(tr.n_sightings - sum(t.n_sightings for t in found["logs"]))}
    row["seconds_search"] = time.perf_counter() - t0
    if found["named"]:
        found, final = plausible_diagnosis(found, opts, progress=lambda s: None)  # as ``aibo diagnose``
        row["named"] = [c.name for c in found["named"]]
        row["effects"] = final.effects
        row["final_pruned"] = int(final.result.pruned_observations)
        row["warnings"] = list(final.result.info.get("warnings", []))
        row["seconds_final"] = sum(final.seconds.values())
        row["restricted_noise_record"] = final.result.info.restricted_noise  # None without --restricted-noise
        row["restricted_variances_record"] = final.result.info.restricted_variances  # None: no variance parameters
    row["seconds"], row["cpu_seconds"] = time.perf_counter() - t0, time.process_time() - c0
    return row


def named_entry(row: dict[str, Any]) -> dict[str, Any] | None:
    """The target effect's entry (``report.json["effects"][k]``: values, intervals, when named), None when not named."""
    return next((e for e in row.get("effects", []) if e["name"] == row["effect"]), None)


def estimates(row: dict[str, Any]) -> dict[str, dict[str, Any]] | None:
    """The named target effect's interval entries (``report.json["effects"][k]["intervals"]``), None when not named."""
    entry = named_entry(row)
    return None if entry is None else entry["intervals"]


def components(row: dict[str, Any]) -> list[tuple[str, int | None]]:
    """(parameter, component index or None for a scalar) of the row's effect, in order."""
    return [(p, None) if np.ndim(v) == 0 else (p, j) for p, v in row["truth"].items() for j in
            ([None] if np.ndim(v) == 0 else range(len(v)))]


def cell(entry: dict[str, Any], j: int | None, fisher: bool = False) -> tuple[float, float | None, list[float] | None]:
    """(estimate, standard error or None, [lo, hi] or None) of component ``j`` of an interval entry (``fisher``: the
    Fisher standard error and interval where the entry has them beside the robust ones, "se_fisher" and
    "interval_95_fisher")."""
    pick = (lambda v: v) if j is None else (lambda v: v[j])
    value = float(pick(entry["value"]))
    tag = "_fisher" if fisher and entry.get("se_fisher") is not None else ""
    se = None if entry.get("se" + tag) is None else float(pick(entry["se" + tag]))
    iv = entry.get("interval_95" + tag)
    return value, se, None if iv is None else [float(pick(iv[0])), float(pick(iv[1]))]


def summary(values: list[float], ses: list[float | None], intervals: list[list[float] | None], true: float) -> dict:
    """The calibration of one parameter over the logs where it was estimated: ``values`` the estimates, ``ses`` their
    standard errors (None: none reported), ``intervals`` their 95% intervals (None: missing), ``true`` the truth.
    Keys: n, missing, covered, coverage and its binomial standard error, bias (mean estimate - truth), bias_mcse, se
    (mean standard error; a half-width / Z95 where none was reported), ratio (bias / se) and ratio_mcse, spread (of
    the estimates) and spread_ratio (spread / se)."""
    n = len(values)
    have = [iv for iv in intervals if iv is not None]
    covered = sum(lo <= true <= hi for lo, hi in have)
    cov = covered / len(have) if have else float("nan")
    err = np.asarray(values, float) - true
    implied = [s if s is not None else (None if iv is None else (iv[1] - iv[0]) / (2 * Z95)) for s, iv in zip(ses, intervals)]
    se = float(np.mean([s for s in implied if s is not None])) if any(s is not None for s in implied) else float("nan")
    spread = float(np.std(values, ddof=1)) if n > 1 else float("nan")
    bias = float(err.mean()) if n else float("nan")
    mcse = spread / np.sqrt(n) if n > 1 else float("nan")
    return {"n": n, "missing": n - len(have), "covered": covered, "coverage": cov,
            "coverage_se": float(np.sqrt(cov * (1 - cov) / len(have))) if have else float("nan"),
            "bias": bias, "bias_mcse": mcse, "se": se, "ratio": bias / se, "ratio_mcse": mcse / se,
            "spread": spread, "spread_ratio": spread / se}


def warned(row: dict[str, Any]) -> bool:
    """Whether `aibo diagnose` would warn about the row's named effect's stated values
    (``effect_sizes.read_with_care``: no interval, moved since named, short of the likelihood's maximum)."""
    from learners.discrepancy.effect_sizes import read_with_care

    entry = named_entry(row)
    return entry is not None and bool(read_with_care(entry))


def unwarned_coverage(cells: list[tuple], flags: list[bool], true: float) -> str:
    """The coverage over the cells whose log the report does not warn about (``warned``), "share (c of n)", and how
    many of the intervals that miss the truth the report warns about ("misses warned: w of m")."""
    held = [(lo <= true <= hi, w) for (_, _, iv), w in zip(cells, flags) if iv is not None for lo, hi in [iv]]
    quiet = [ok for ok, w in held if not w]
    misses = [w for ok, w in held if not ok]
    share = f"{sum(quiet) / len(quiet):.0%} ({sum(quiet)} of {len(quiet)})" if quiet else "-"
    return share + (f"; misses warned: {sum(misses)} of {len(misses)}" if misses else "")


def table(rows: list[dict[str, Any]], fisher: bool = False) -> str:
    """The markdown table (module docstring): per effect, parameter (component) and noise preset, over the logs where
    the effect was named, with how many logs named it (``fisher``: of the Fisher intervals, ``cell``), and the coverage
    over the logs whose report gives no warning about the effect's values (``warned``)."""
    lines = ["| effect | parameter | preset | truth | named | coverage (+- s.e.) | bias | SE | bias / SE (+- MC s.e.) | "
             "spread / SE | missing | not warned: coverage |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    order = {e: k for k, e in enumerate(STRENGTH)}
    for effect in sorted({r["effect"] for r in rows}, key=lambda e: (order.get(e, len(order)), e)):
        rs = [r for r in rows if r["effect"] == effect]
        for pname, j in components(rs[0]):
            true = rs[0]["truth"][pname] if j is None else rs[0]["truth"][pname][j]
            label = pname if j is None else f"{pname}[{j}]"
            for preset in [p for p in (*PRESETS, WHEELED) if any(r["preset"] == p for r in rs)]:
                logs = [r for r in rs if r["preset"] == preset]
                named = [r for r in logs if named_entry(r) is not None]
                cells = [cell(named_entry(r)["intervals"][pname], j, fisher) for r in named]
                head = f"| {effect} | {label} | {preset} | {true:.4g} | {len(cells)} of {len(logs)} |"
                if not cells:
                    lines.append(head + " | | | | | | |")
                    continue
                s = summary([c[0] for c in cells], [c[1] for c in cells], [c[2] for c in cells], true)
                lines.append(head + f" {s['coverage']:.0%} +- {s['coverage_se']:.0%} ({s['covered']} of "
                             f"{s['n'] - s['missing']}) | {s['bias']:+.3g} | {s['se']:.3g} | {s['ratio']:+.2f} +- "
                             f"{s['ratio_mcse']:.2f} | {s['spread_ratio']:.2f} | {s['missing']} | "
                             f"{unwarned_coverage(cells, [warned(r) for r in named], true)} |")
    return "\n".join(lines) + "\n"


def all_rows(out: Path) -> list[dict[str, Any]]:
    """The rows of every OUT/rows*.jsonl (one per process that ran), in log order."""
    rows = [r for path in sorted(out.glob("rows*.jsonl")) for r in read_jsonl(path)]
    return sorted(rows, key=lambda r: r["log"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", type=int, default=100, help="logs per effect (log i: seed SEED + i, preset PRESETS[i %% 2])")
    ap.add_argument("--first-log", type=int, default=0, help="start at this log (a second process can take others)")
    ap.add_argument("--effects", default=",".join(STRENGTH), help="comma-separated, in the order run (default: all)")
    ap.add_argument("--minutes", type=float, default=5.0, help="log length (default 5: 9000 frames)")
    ap.add_argument("--presets", default=",".join(PRESETS),
                    help="run only the logs of these noise presets (an effect of continuous commands: every log)")
    ap.add_argument("--out", default="runs/calibration")
    ap.add_argument("--table", action="store_true", help="only print the table of the rows in OUT")
    ap.add_argument("--strength", action="append", default=[], metavar="EFFECT.PARAM=VALUE",
                    help="simulate an effect at another strength (repeatable; its own --out)")
    ap.add_argument("--restricted-noise", action="store_true",
                    help="the final fit with the motion noise at the restricted likelihood's maximum (``aibo diagnose "
                         "--restricted-noise``); its rows need their own --out")
    ap.add_argument("--maximum-likelihood-variances", action="store_true",
                    help="the effects' variance parameters at the likelihood's maximum, not stepped to the restricted "
                         "likelihood's (``EMOptions.restricted_variances`` off); its rows need their own --out")
    ap.add_argument("--fisher", action="store_true",
                    help="tabulate the Fisher intervals where the rows have them beside the robust ones (OUT/table-fisher.md)")
    args = ap.parse_args()
    out = Path(args.out)
    rows = all_rows(out)
    if not args.table:
        from study import resume

        effects = [e.strip() for e in args.effects.split(",") if e.strip()]
        unknown = [e for e in effects if e not in STRENGTH]
        if unknown:
            ap.error(f"--effects: no strength for {unknown[0]!r} (valid: {', '.join(STRENGTH)})")
        try:
            set_strength(args.strength)
        except ValueError as err:
            ap.error(str(err))
        other = next((r for r in rows if r["effect"] in effects and r["params"] != STRENGTH[r["effect"]]), None)
        if other is not None:
            ap.error(f"--out {out}: holds rows of {other['effect']} at {other['params']}, not "
                     f"{STRENGTH[other['effect']]}: give this strength its own --out")
        # rows written before ``restricted_variances`` existed were fitted at the likelihood's maximum
        kind = {"restricted_noise": args.restricted_noise, "restricted_variances": not args.maximum_likelihood_variances}
        for key, flag in (("restricted_noise", "--restricted-noise"), ("restricted_variances", "--maximum-likelihood-variances")):
            mixed = next((r for r in rows if r.get(key, False) != kind[key]), None)
            if mixed is not None:
                ap.error(f"--out {out}: holds rows {'with' if mixed.get(key, False) else 'without'} {key}: give the "
                         f"other kind its own --out ({flag})")
        # log by log, each effect in turn: a study stopped early has as many logs of every effect
        done = {(r["effect"], r["log"], r["minutes"]) for r in rows}
        presets = {p.strip() for p in args.presets.split(",")}
        if not presets <= set(PRESETS):
            ap.error(f"--presets {args.presets!r}: valid presets are {', '.join(PRESETS)}")
        keys = [{"effect": e, "log": i, "minutes": args.minutes} for i in range(args.first_log, args.logs) for e in effects
                if (e, i, args.minutes) not in done and (PRESETS[i % len(PRESETS)] in presets or wheeled(e))]
        rows_file = "rows.jsonl" if args.first_log == 0 else f"rows-from-{args.first_log}.jsonl"

        def progress(r: dict[str, Any], md: str) -> None:
            est = estimates(r)
            short = (lambda v: None if v is None else np.round(np.asarray(v, float), 4).tolist())
            text = "not named" if est is None else "; ".join(f"{p} {short(v['value'])} {short(v['interval_95'])}"
                                                            for p, v in est.items())
            print(f"{r['effect']:25s} log {r['log']:3d} ({r['preset']:9s} seed {r['seed']}): named {r['named']}; {text} "
                  f"[{r['seconds']:.0f} s, {r['cpu_seconds']:.0f} s CPU]", flush=True)

        resume(out, rows_file, keys, lambda k: one(k["effect"], k["log"], k["minutes"], *kind.values()),
               lambda _: table(all_rows(out)), progress)
        rows = all_rows(out)
    md = table(rows, args.fisher)
    atomic_write(out / ("table-fisher.md" if args.fisher else "table.md"), lambda f: f.write(md.encode()))
    print(md)


if __name__ == "__main__":
    main()
