"""Which named effect moves the forward speed: per MRCLAM Dataset 7 robot half, ``aibo learn``'s model of the half with
each effect ``aibo diagnose`` named on it added alone, and with all of them, each fitted on that half as diagnose's
final fit fits learn's start (``learners.discrepancy.final.fit_from``: the curve held until EM converges, then
freed), and scored against Vicon on the other half.

    python scripts/mrclam_ablation.py [DATA] [--crossval /tmp/mrclam_crossval] [--out /tmp/mrclam_ablation]
                                      [--robots 1,2,3,4,5]

Reads the models ``scripts/mrclam_crossval.py`` wrote in its ``--out`` folder (``--crossval``; run it first): each
half's ``aibo learn`` model and ``aibo diagnose`` model. The effects are added at the diagnosed model's values (its
final fit's), and the sightings are the half's without the gross outliers learn's model gates out (as the search sets
them aside). Scores (``learners.scoring.velocity_scores``, 1 s windows): forward speed RMS error (mm/s) on the other
half, and the model's mean forward speed there against Vicon's (a scale of the velocities shows as a mean short or
long); with each fit's log-likelihood of the half it was fitted on (nats, ``train_loglik``), and the robot's own gain
driving straight in each half (``straight_gain``). One row per (robot, direction) in OUT/rows.jsonl (a rerun skips
finished rows); OUT/table.md rewritten after each.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mrclam_crossval import halves, stem  # noqa: E402
from study import data_folder, mrclam_parser, resume, robots  # noqa: E402

import aibo  # noqa: E402,F401  (one BLAS thread per process, as the commands run)
from learners.discrepancy.final import HOLD_LEARNED_CURVE, FinalStart, final_options, fit_from  # noqa: E402
from learners.discrepancy.fitting import train_loglik  # noqa: E402
from learners.discrepancy.search import drop_outliers  # noqa: E402
from learners.em.options import EMOptions  # noqa: E402
from learners.model.io import load_model  # noqa: E402
from learners.scoring import measured_window_velocities, model_window_velocities, velocity_scores  # noqa: E402

DIRECTIONS = ("first->second", "second->first")


def forward(model, test) -> dict:
    """``model``'s forward speed on the half ``test`` against Vicon: RMS error (mm/s) and the mean forward speed of the
    model and of Vicon over the same 1 s windows (mm/s)."""
    win, v = measured_window_velocities(test)
    p = model_window_velocities(model, test, win)
    return {"vx_rms": velocity_scores(model, [test])["vx_rms"], "mean_model": float(p[:, 0].mean()),
            "mean_vicon": float(v[:, 0].mean())}


def straight_gain(half, lag_s: float) -> tuple[float, int]:
    """(Vicon's forward speed over the commanded one, median over the 1 s windows of ``half`` driven straight at a steady
    command: the commands shifted by ``lag_s`` (s), constant over the window, above 20 mm/s and below 0.05 rad/s; how
    many windows): the robot's own gain where no model of turns or changes of command is involved."""
    win, v = measured_window_velocities(half)
    shift = int(round(lag_s / half.dt))
    c = np.vstack([np.repeat(half.controls[:1], shift, axis=0), half.controls[:len(half.controls) - shift]])
    steady = np.array([np.ptp(c[a:b, 0]) < 1.0 and np.ptp(c[a:b, 1]) < 1e-3 for a, b in win], dtype=bool)
    cmd = np.array([c[a:b].mean(axis=0) for a, b in win])
    m = steady & (cmd[:, 0] > 20.0) & (np.abs(cmd[:, 1]) < 0.05)
    return float(np.median(v[m, 0] / cmd[m, 0])), int(m.sum())


def row(data: Path, crossval: Path, robot: int, direction: str) -> dict:
    """The fits of one half (module docstring): {"learn", "diagnose", "held" (learn's model refitted alone), one entry
    per named effect alone, "all"}, each with its scores and ``train_loglik``."""
    h1, h2 = halves(data, robot)
    fit, test = (h1, h2) if direction == "first->second" else (h2, h1)
    learn = load_model(crossval / f"{stem(robot, direction)}_learn.json")
    diag = load_model(crossval / f"{stem(robot, direction)}_diagnose" / "model.json")
    names = [e.name for e in diag.effects if learn.effect(e.name) is None]  # learn may hold the lag and the shrink
    (clean,), _ = drop_outliers(learn, [fit])
    fopts = final_options(EMOptions(lag_search=False))
    fits = {"learn": learn, "diagnose": diag}
    starts = {"held": learn, **{n: learn.with_effect(diag.effect(n)) for n in names}}
    if len(names) > 1:
        starts["all"] = learn
        for n in names:
            starts["all"] = starts["all"].with_effect(diag.effect(n))
    for key, start in starts.items():
        fits[key] = fit_from(FinalStart(key, start, HOLD_LEARNED_CURVE), [clean], fopts).params
    lag = learn.effect("actuation_lag")
    lag_s = 0.0 if lag is None else float(lag.lag_s)
    rec = {"robot": robot, "direction": direction, "named": names,
           "straight_gain": {"fitted": straight_gain(fit, lag_s), "scored": straight_gain(test, lag_s)}}
    for key, m in fits.items():
        rec[key] = {**forward(m, test), "loglik": train_loglik(m, [clean])}
    return rec


def table(rows: list[dict]) -> str:
    head = ("| robot | fitted on -> scored on | forward mm/s against Vicon (learn's model refitted as learn's start is; "
            "+ each effect alone; + all; diagnose's model) | mean forward mm/s: Vicon / learn / diagnose | "
            "log-likelihood gain over the refitted learn (nats) | driving straight, Vicon / command: fitted half / "
            "scored half (windows) |\n|---|---|---|---|---|---|")
    lines = []
    for r in sorted(rows, key=lambda r: (r["robot"], r["direction"])):
        keys = ["held", *r["named"], *(["all"] if len(r["named"]) > 1 else [])]
        ref = r["held"]["vx_rms"]
        errors = "; ".join(f"{k if k != 'held' else 'learn refitted'} {r[k]['vx_rms']:.2f}"
                           + ("" if k == "held" else f" ({100 * (r[k]['vx_rms'] / ref - 1):+.0f}%)") for k in keys)
        errors += f"; diagnose {r['diagnose']['vx_rms']:.2f}"
        gains = "; ".join(f"{k} {r[k]['loglik'] - r['held']['loglik']:+.0f}" for k in keys[1:])
        lines.append(f"| {r['robot']} | {r['direction'].replace('->', ' -> ')} | {errors} | "
                     f"{r['learn']['mean_vicon']:.1f} / {r['learn']['mean_model']:.1f} / {r['diagnose']['mean_model']:.1f}"
                     f" | {gains} | {r['straight_gain']['fitted'][0]:.3f} ({r['straight_gain']['fitted'][1]}) / "
                     f"{r['straight_gain']['scored'][0]:.3f} ({r['straight_gain']['scored'][1]}) |")
    return head + "\n" + "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = mrclam_parser(__doc__, "/tmp/mrclam_ablation")
    ap.add_argument("--crossval", default="/tmp/mrclam_crossval",
                    help="scripts/mrclam_crossval.py's --out folder, with its models (default /tmp/mrclam_crossval)")
    args = ap.parse_args(argv)
    data = data_folder("mrclam_ablation", args.data)
    if data is None:
        return 2
    crossval = Path(args.crossval)
    keys = [{"robot": r, "direction": d} for r in robots(args.robots) for d in DIRECTIONS]
    missing = [k for k in keys if not (crossval / f"{stem(k['robot'], k['direction'])}_learn.json").is_file()]
    if missing:
        print(f"mrclam_ablation: {crossval}: no models of robot {missing[0]['robot']} "
              f"({missing[0]['direction']}): run scripts/mrclam_crossval.py --out {crossval} first", file=sys.stderr)
        return 2
    resume(Path(args.out), "rows.jsonl", keys, lambda k: row(data, crossval, k["robot"], k["direction"]), table,
           lambda _, md: print(md.splitlines()[-1], flush=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
