"""Monte Carlo study of the EM learner: many independent simulated logs, every variant of the fit.

    python scripts/monte_carlo.py --logs 12 --steps 27000 --json runs/mc15.json        # the docs/results.md table
    python scripts/monte_carlo.py --variants default --logs 100 --steps 9000 27000 108000 \\
        --robots 0 1 2 3 --noise paper-sim aibo --json runs/mc_sweep.json                # the failure sweep
    python scripts/monte_carlo.py --from-json runs/mc15.json                             # print the tables again

Log i of a cell (noise preset, length) is ``aibo_gym.collect.collect`` of robot ``robots[i % len]``
with seed ``seed + i``, so every number is reproducible from the command. Each variant fits each
log from the paper's start; per fit: the errors (``learners.metrics.model_errors``), failure (vx
or vy error above 5% of the range), iterations (all starts' E-steps), wall and CPU seconds of the EM
fit, and, for ``--se-variants``, the standard errors (``learners.em.uncertainty``), timed apart (with
the scoring finish they come with the fit, at no extra time), and the bound they imply (``bound``).
Printed: one markdown table per cell (mean over logs; failures counted apart and left out of the
means; error / bound is the mean error over the mean bound of the same logs), and the standard
errors against the spread of the estimates over the logs of each robot.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace

import numpy as np

from aibo_gym.collect import collect
from learners.em.learner import EMLearner
from learners.em.options import EMOptions
from learners.metrics import model_errors, velocity_bound
from learners.oracle import OracleLearner

VARIANTS = {
    "default (inverse, 3 starts)": EMOptions(),
    "paper recipe": EMOptions.paper(),
    "cubic, 1 start (old default)": EMOptions(basis="power", starts=1),
    "cubic, 3 starts": EMOptions(basis="power", starts=3),
    "inverse, 1 start": EMOptions(basis="inverse", starts=1),
    "default without the alias search": EMOptions(alias_search=False),
    "default with the scoring finish": EMOptions(finish="scoring"),
    # issue 19's stop rule (EMOptions.patience): the old one, and the new one with the old screening
    "before the early stop (0.1 nats, patience 50, screened 30)": EMOptions(min_improvement=0.1, patience=50,
                                                                             screen_iter=30),
    "default, starts screened 30 iterations": EMOptions(screen_iter=30),
}
SHORT = {"default": "default (inverse, 3 starts)", "paper": "paper recipe", "old": "cubic, 1 start (old default)",
         "noalias": "default without the alias search",
         "finish": "default with the scoring finish", "slow": "before the early stop (0.1 nats, patience 50, screened 30)",
         "screen30": "default, starts screened 30 iterations"}
#: A fit whose vx or vy error exceeds this fraction of the range is a failure (a wrong optimum).
FAIL_REL = 0.05
KEYS = ("vx_rel", "vy_rel", "vtheta_rel", "sigma_height_rel", "sigma_angle_rel", "sensor_rms_px")


def fit_one(tr, name: str, opts: EMOptions, seed: int, with_se: bool) -> dict:
    """One EM fit of ``tr`` (uncertainty timed apart); the row of the study."""
    opts = replace(opts, seed=seed, uncertainty=with_se)
    t0, c0 = time.perf_counter(), time.process_time()
    res = EMLearner(opts, check_field=False).fit([tr])
    se_s, se_cpu = res.info.get("uncertainty_seconds", 0.0), res.info.get("uncertainty_cpu_seconds", 0.0)
    row = {"variant": name, "seconds": time.perf_counter() - t0 - se_s, "cpu_seconds": time.process_time() - c0 - se_cpu,
           "iterations": res.info["iterations_all_starts"], "winner_iterations": res.iterations,
           "converged": res.converged, "off_field": res.info["off_field_fraction"],
           "starts": res.info.get("starts", []), **model_errors(res.params, [tr]).as_dict()}
    row["failure"] = bool(row["vx_rel"] > FAIL_REL or row["vy_rel"] > FAIL_REL)
    row["starts_disagree"] = any(w.startswith("starts disagree") for w in res.info["warnings"])
    row["may_be_wrong"] = any(w.startswith("may be a wrong optimum") for w in res.info["warnings"])
    row["alias_search"] = res.info.get("alias_search")
    row["velocities"] = res.params.action.velocities.tolist()
    row["sigma_height"], row["sigma_angle"] = res.params.sensor.sigma_size, res.params.sensor.sigma_bearing
    se = res.info.get("standard_errors")
    if se:
        row["se_seconds"], row["se_cpu_seconds"] = se_s, se_cpu
        row["se_velocities"] = se["action_model.velocities"]
        row["se_sigma_height"] = se["sensor_model.sigma_height"]
        row["se_sigma_angle"] = se["sensor_model.sigma_angle"]
        row["condition_number"] = res.info["information"]["condition_number"]
        row.update(velocity_bound(row["se_velocities"], tr.truth["velocities"]))
    row["scoring"] = res.info.get("scoring")
    return row


def cell_logs(noise: str, steps: int, n: int, robots: list[int], seed: int):
    """(robot, seed, log) of a cell, in order."""
    for i in range(n):
        robot = robots[i % len(robots)]
        yield robot, seed + i, collect({"noise": noise, "robot_seed": robot, "max_steps": steps}, steps=steps,
                                       seed=seed + i, progress=False)


def _mean(rows: list[dict], key: str) -> float:
    return float(np.mean([r[key] for r in rows])) if rows else float("nan")


def table(rows: list[dict], variants: list[str]) -> list[str]:
    """Markdown rows: mean over the logs that did not fail, failures counted."""
    out = ["| variant | logs | failures | vx | vy | vtheta | sigma_h | sigma_a | sensor px | iterations | "
           "wall s | with SE s | error / bound (vx / vy / vtheta) |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name in ["oracle (true poses)", *variants]:
        sel = [r for r in rows if r["variant"] == name]
        if not sel:
            continue
        ok = [r for r in sel if not r["failure"]]
        fails = len(sel) - len(ok)
        disagree = sum(r.get("starts_disagree", False) for r in sel)
        flagged = sum(r.get("may_be_wrong", False) for r in sel if r["failure"])
        fixed = sum(bool((r.get("alias_search") or {}).get("changed")) for r in sel)
        cells = [str(len(sel)), f"{fails}" + (f" ({disagree} times the starts disagreed)" if disagree else "")
                 + (f" ({flagged} flagged)" if flagged else "") + (f" ({fixed} aliases fixed)" if fixed else "")]
        cells += [f"{100 * _mean(ok, k):.2f}%" for k in KEYS[:5]] + [f"{_mean(ok, 'sensor_rms_px'):.3f}"]
        cells += [f"{_mean(sel, 'iterations'):.0f}", f"{_mean(sel, 'seconds'):.2f}"]
        with_se = [r for r in sel if "se_seconds" in r]
        cells.append(f"{float(np.mean([r['seconds'] + r['se_seconds'] for r in with_se])):.2f}" if with_se else "")
        bounded = [r for r in ok if "vx_bound" in r]
        cells.append(" / ".join(f"{_mean(bounded, f'{n}_rel') / _mean(bounded, f'{n}_bound'):.2f}"
                                for n in ("vx", "vy", "vtheta")) if bounded else "")
        out.append(f"| {name} | " + " | ".join(cells) + " |")
    return out


def se_check(rows: list[dict]) -> list[str]:
    """Standard errors vs the spread over logs of one robot: pooled over commands, per component."""
    out = []
    groups = sorted({(r["variant"], r["noise"], r["steps"], r["robot"]) for r in rows if "se_velocities" in r})
    for group in groups:
        sel = [r for r in rows if (r["variant"], r["noise"], r["steps"], r["robot"]) == group and "se_velocities" in r
               and not r["failure"]]
        robot = group[3]
        if len(sel) < 3:
            continue
        est = np.array([r["velocities"] for r in sel])  # (n, 40, 3)
        se = np.array([r["se_velocities"] for r in sel], dtype=float)
        spread = est.std(axis=0, ddof=1)  # per command and component
        ratio = np.sqrt(np.nanmean(se**2, axis=(0, 1))) / np.sqrt(np.nanmean(spread**2, axis=0))
        z = (est - np.array(sel[0]["true_velocities"])) / se
        rms_z = np.sqrt(np.nanmean(z**2, axis=(0, 1)))
        sig = {k: np.std([r[k] for r in sel], ddof=1) / np.mean([r[f"se_{k}"] for r in sel])
               for k in ("sigma_height", "sigma_angle")}
        out.append(f"| {sel[0]['variant']} | {sel[0]['noise']} | {sel[0]['steps'] / 1800:.0f} min | robot {robot} | "
                   f"{len(sel)} | " + " / ".join(f"{v:.2f}" for v in ratio) + " | "
                   + " / ".join(f"{v:.2f}" for v in rms_z) + f" | {1 / sig['sigma_height']:.2f} / {1 / sig['sigma_angle']:.2f}"
                   f" | {_mean(sel, 'se_seconds'):.2f} |")
    if out:
        out = ["| variant | noise | length | robot | logs | SE / spread (vx / vy / vtheta) | RMS z vs truth | "
               "SE / spread (sigma_h / sigma_a) | SE s |", "|---|---|---|---|---|---|---|---|---|"] + out
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--logs", type=int, default=12, help="logs per cell (noise preset x length)")
    ap.add_argument("--steps", type=int, nargs="+", default=[27000], help="log lengths in frames (30 per second)")
    ap.add_argument("--robots", type=int, nargs="+", default=[0], help="robot seeds, used in turn")
    ap.add_argument("--noise", nargs="+", default=["paper-sim"], choices=["paper-sim", "aibo"])
    ap.add_argument("--variants", nargs="+", default=["all"], help=f"'all', or names/short names {list(SHORT)}")
    ap.add_argument("--se-variants", nargs="*", default=["default"], help="variants whose standard errors are computed")
    ap.add_argument("--seed", type=int, default=100, help="log i of a cell has seed SEED + i")
    ap.add_argument("--oracle", action="store_true", help="also the oracle (true poses)")
    ap.add_argument("--json", help="write every row to this file")
    ap.add_argument("--from-json", help="only print the tables of a study written by --json")
    args = ap.parse_args()
    if args.from_json:
        return report(json.load(open(args.from_json))["rows"])
    names = list(VARIANTS) if args.variants == ["all"] else [SHORT.get(v, v) for v in args.variants]
    se_names = {SHORT.get(v, v) for v in args.se_variants}
    rows: list[dict] = []
    for noise in args.noise:
        for steps in args.steps:
            for robot, seed, tr in cell_logs(noise, steps, args.logs, args.robots, args.seed):
                base = {"noise": noise, "steps": steps, "robot": robot, "seed": seed,
                        "true_velocities": tr.truth["velocities"]}
                if args.oracle:
                    rows.append({**base, "variant": "oracle (true poses)", "iterations": 1, "seconds": 0.0,
                                 "cpu_seconds": 0.0, "failure": False,
                                 **model_errors(OracleLearner().fit([tr]).params, [tr]).as_dict()})
                for name in names:
                    rows.append({**base, **fit_one(tr, name, VARIANTS[name], seed, name in se_names)})
                    r = rows[-1]
                    print(f"{noise} {steps} robot {robot} seed {seed} {name:30s} it {r['iterations']:4d} "
                          f"{r['seconds']:5.1f} s vx {100 * r['vx_rel']:.2f}% vy {100 * r['vy_rel']:.2f}% "
                          f"vth {100 * r['vtheta_rel']:.2f}% px {r['sensor_rms_px']:.3f}"
                          + ("  FAILURE" if r["failure"] else ""), flush=True)
                if args.json:
                    with open(args.json, "w") as f:
                        json.dump({"args": vars(args), "rows": rows}, f)
    report(rows)


def report(rows: list[dict]) -> None:
    """Print one table per cell (noise, length), then the standard errors against the spread."""
    names = list(dict.fromkeys(r["variant"] for r in rows if r["variant"] != "oracle (true poses)"))
    for noise, steps in dict.fromkeys((r["noise"], r["steps"]) for r in rows):
        cell = [r for r in rows if r["noise"] == noise and r["steps"] == steps]
        robots = sorted({r["robot"] for r in cell})
        n_logs = len({r["seed"] for r in cell})
        print(f"\n{n_logs} logs, {noise} noise, {steps} frames ({steps / 1800:.0f} min), robots {robots}: "
              "mean over the logs that did not fail\n")
        print("\n".join(table(cell, names)))
    print("\nStandard errors against the spread over logs of one robot (SE / spread and RMS z should be ~1)\n")
    print("\n".join(se_check(rows)))


if __name__ == "__main__":
    main()
