"""How often does the calibrated check disagree with a log its model is right about? Its threshold is set so that a
right model shows no disagreement in 95% of checks (``experiments.calibrated``: Bonferroni over the statistics,
Student t over the replicas); this measures it.

    python scripts/check_null.py [--seeds 50] [--first-seed 6000] [--presets aibo,paper-sim] [--minutes 5]
                                 [--model base|learn] [--replicas 16] [--jobs 2] [--out DIR] [--table]
                                 [--exchangeable R]

Blind simulated logs with no effect, ``--seeds`` per noise preset (interleaved, so a run stopped early covers both);
on each, a model of it and the calibrated check of that model (``predictive_check``, the replicas' seed 0). The model
(``--model``): ``base``, the base model of ``aibo diagnose`` (``signatures_null.fitted_base``: the search's base fit on
the training half, outliers set aside, polished; cached in ``models/``), what its check "before the named effects"
checks; ``learn``, ``aibo learn``'s fit of the whole log (its default options; outliers set aside), the start of
``aibo diagnose``'s final fit, which writes the model the check "after" checks. Reported: per preset, the logs with
any disagreement (target: at most 5%, with its exact 95% upper bound), the count of disagreements per log, and which
statistics disagreed. Resumable (``runs.jsonl`` in
``--out``, default ``runs/check_null/MODEL``); writes ``check_null.md`` there. ``--presets`` may name ``wheeled``
(``WheeledRobot-v0``, random start, 10 frames a second; ``--model learn`` only).

``--exchangeable R`` measures the threshold alone, where the model is exactly right by construction: per log, R
replicas of its model (``replica_statistics``, saved in ``replicas/`` and reused), and each check made of one replica
as the measured log against 4, 8, 16 or 24 others (``COUNTS``) drawn at random (``DRAWS`` draws each, seeded): the
share of those checks with any disagreement is the threshold's family false-alarm rate given the statistics' real (not
Gaussian) spread. Also tabulated (and drawn: ``false_alarms.png``) with the residual signatures' strength as
sqrt(-log10 p) (the stored (-log10 p)^(1/3) to the power 3/2), the transform the check used before: the evidence for
the cube root (``learners.discrepancy.statistics``).
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diagnose_power import upper95  # noqa: E402
from signatures_null import fitted_base  # noqa: E402

from aibo_core.atomic import atomic_write, read_jsonl, write_jsonl  # noqa: E402
from aibo_core.trajectory import Trajectory, blind  # noqa: E402
from aibo_core.workers import process_pool  # noqa: E402
from aibo_gym.collect import collect  # noqa: E402
from aibo_gym.collect_wheeled import collect_wheeled  # noqa: E402
from experiments.calibrated import FAMILY_ALPHA, REPLICAS, Check, predictive_check, replica_statistics  # noqa: E402
from learners.discrepancy.search import drop_outliers  # noqa: E402
from learners.em.learner import EMLearner  # noqa: E402
from learners.em.options import EMOptions  # noqa: E402
from learners.model.model import Model  # noqa: E402


def fitted(tr: Trajectory, which: str, cache: Path) -> tuple[Model, list[Trajectory]]:
    """(``which`` model of ``tr`` (module docstring), the log with its outliers set aside)."""
    if which == "base":
        return fitted_base(tr, cache, refit=False)
    model = EMLearner(EMOptions(seed=0)).fit([tr]).params
    return model, drop_outliers(model, [tr])[0]


DRAWS = 2000  # --exchangeable: checks drawn per log and count of replicas
COUNTS = (4, 8, 16, 24)  # --exchangeable: the counts of replicas a check is made with


def effect_free(seed: int, preset: str, minutes: float) -> Trajectory:
    """A blind effect-free log: ``AiboBeacons-v0`` with the noise ``preset``, or ``WheeledRobot-v0`` (``wheeled``)."""
    if preset == "wheeled":
        return blind(collect_wheeled({"start_pose": "random"}, int(minutes * 600), seed=seed))
    return blind(collect({"noise": preset, "effects": {}}, int(minutes * 60 * 30), seed=seed))


def one(seed: int, preset: str, minutes: float, models: Path, which: str, replicas: int, jobs: int,
        tracking: bool = False) -> dict:
    """One effect-free blind log: the check of its ``which`` model (its replicas steered along the model's smoothed
    path with ``tracking``), (statistic, z) of every disagreement."""
    tr = effect_free(seed, preset, minutes)
    model, logs = fitted(tr, which, models / f"{preset}-{seed}.json")
    check = predictive_check(model, logs, replicas=replicas, seed=0, jobs=jobs, tracking=tracking)
    return {"seed": seed, "preset": preset, "minutes": minutes, "model": which, "replicas": replicas,
            "tracking": tracking,
            "statistics": len(check.names),
            "threshold": check.threshold, "failed_replicas": len(check.failed),
            "disagreements": [[n, z] for n, z in check.disagreements()]}


def exchangeable(seed: int, preset: str, minutes: float, models: Path, which: str, n: int, jobs: int) -> dict:
    """One effect-free log: ``n`` replicas of its ``which`` model (saved in ``replicas/``, reused when there), and per
    count of ``COUNTS`` the share of checks (one replica against that many others) with any disagreement, with the
    strengths as stored and as sqrt(-log10 p)."""
    saved = models.parent / "replicas" / f"{preset}-{seed}.npz"
    if saved.exists():
        with np.load(saved) as z:
            names, values = [str(k) for k in z["names"]], z["values"]
    else:
        tr = effect_free(seed, preset, minutes)
        model, logs = fitted(tr, which, models / f"{preset}-{seed}.json")
        with process_pool(jobs) as pool:  # its workers exit with this process (a study stopped by hand)
            rows = list(pool.map(replica_statistics, [model] * n, [logs] * n, [1000 + 17 * i for i in range(n)]))
        names = sorted(set.intersection(*(set(r) for r in rows)))
        values = np.array([[r[k] for k in names] for r in rows])
        atomic_write(saved, lambda f: np.savez(f, values=values, names=np.array(names)))
    as_sqrt = values.copy()
    strengths = [k.endswith("(strength)") for k in names]
    as_sqrt[:, strengths] = values[:, strengths] ** 1.5
    return {"seed": seed, "preset": preset, "minutes": minutes, "model": which, "exchangeable": len(values),
            "false_alarm": {str(r): alarm_share(names, values, r, seed) for r in COUNTS},
            "false_alarm_sqrt": {str(r): alarm_share(names, as_sqrt, r, seed) for r in COUNTS}}


def alarm_share(names: list[str], values: np.ndarray, replicas: int, seed: int) -> float:
    """Share of ``DRAWS`` checks (one row of ``values`` as the measured log, ``replicas`` other rows as its replicas)
    with any disagreement."""
    rng = np.random.default_rng(seed)
    hits = 0
    for _ in range(DRAWS):
        pick = rng.choice(len(values), replicas + 1, replace=False)
        hits += bool(Check(names, values[pick[0]], values[pick[1:]]).disagreements())
    return hits / DRAWS


def exchangeable_summary(done: list[dict]) -> list[str]:
    """Per preset and count of replicas: the mean family false-alarm share of the exchangeable checks (range over
    the logs), with each strength transform."""
    lines = ["| preset | logs | replicas | any disagreement: (-log10 p)^(1/3), mean (range over the logs) | "
             "sqrt(-log10 p) |", "|---|---|---|---|---|"]
    for preset in sorted({r["preset"] for r in done}) + ["all"]:
        runs = [r for r in done if preset in ("all", r["preset"])]
        for count in COUNTS:
            cube, root = (np.array([r[k][str(count)] for r in runs]) for k in ("false_alarm", "false_alarm_sqrt"))
            lines.append(f"| {preset} | {len(runs)} | {count} of {runs[0]['exchangeable']} | "
                         f"**{100 * cube.mean():.1f}%** ({100 * cube.min():.1f}-{100 * cube.max():.1f}%) | "
                         f"{100 * root.mean():.1f}% ({100 * root.min():.1f}-{100 * root.max():.1f}%) |")
    return lines


def false_alarm_figure(done: list[dict], path: Path) -> None:
    """The exchangeable checks' mean false-alarm share against the count of replicas, per generator and strength
    transform, beside the nominal 5%."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4))
    for preset, color in zip(sorted({r["preset"] for r in done}), ("C0", "C1", "C2", "C3")):
        runs = [r for r in done if r["preset"] == preset]
        for key, style, label in (("false_alarm", "-o", "(-log10 p)^(1/3)"), ("false_alarm_sqrt", "--s", "sqrt(-log10 p)")):
            rates = [100 * np.mean([r[key][str(c)] for r in runs]) for c in COUNTS]
            ax.plot(COUNTS, rates, style, color=color, label=f"{preset}, {label}")
    ax.axhline(100 * FAMILY_ALPHA, color="k", ls=":", label="nominal")
    ax.set_xticks(COUNTS)
    ax.set_xlabel("replicas in the check")
    ax.set_ylabel("checks with any disagreement (%)")
    ax.set_ylim(0, None)
    ax.legend(fontsize=7, ncol=2)
    ax.set_title("The calibrated check where the model is right (one replica against others)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def summary(done: list[dict]) -> list[str]:
    """The tables of the module docstring, as markdown lines."""
    lines = ["| preset | logs | with any disagreement | 95% upper bound | disagreements per log: 0 / 1 / 2+ | "
             "statistics that disagreed (times) |", "|---|---|---|---|---|---|"]
    for preset in sorted({r["preset"] for r in done}) + ["both"]:
        runs = [r for r in done if preset in ("both", r["preset"])]
        n, counts = len(runs), Counter(min(len(r["disagreements"]), 2) for r in runs)
        k = n - counts[0]
        which = Counter(name for r in runs for name, _ in r["disagreements"])
        lines.append(f"| {preset} | {n} | **{k}** ({100 * k / max(n, 1):.0f}%) | {100 * upper95(k, n):.1f}% | "
                     f"{counts[0]} / {counts[1]} / {counts[2]} | "
                     + "; ".join(f"{name} ({c})" for name, c in which.most_common()) + " |")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=50, help="effect-free logs per noise preset")
    ap.add_argument("--presets", default="aibo,paper-sim")
    ap.add_argument("--minutes", type=float, default=5.0)
    ap.add_argument("--first-seed", type=int, default=6000, help="the logs' seeds are this and the next --seeds - 1")
    ap.add_argument("--model", choices=("base", "learn"), default="base")
    ap.add_argument("--replicas", type=int, default=REPLICAS)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default=None, help="default runs/check_null/MODEL")
    ap.add_argument("--table", action="store_true", help="print the table of the rows so far and stop")
    ap.add_argument("--tracking", action="store_true",
                    help="the replicas steered along the model's smoothed path (predictive_check(tracking=True); "
                         "continuous commands only)")
    ap.add_argument("--exchangeable", type=int, default=0, metavar="R",
                    help="measure the threshold alone: R replicas per log, each checked against --replicas others")
    args = ap.parse_args()
    if 0 < args.exchangeable <= max(COUNTS):
        ap.error(f"--exchangeable: at least {max(COUNTS) + 1} replicas (one checked against up to {max(COUNTS)} others), "
                 f"got {args.exchangeable}")
    out = Path(args.out or f"runs/check_null/{args.model}" + ("-exchangeable" if args.exchangeable else ""))
    models = out / "models"
    models.mkdir(parents=True, exist_ok=True)
    if args.exchangeable:
        (out / "replicas").mkdir(exist_ok=True)
    done_path = out / "runs.jsonl"
    done = read_jsonl(done_path)
    have = {(r["seed"], r["preset"]) for r in done}
    for s in range(0 if args.table else args.seeds):
        for preset in args.presets.split(","):
            if (args.first_seed + s, preset) in have:
                continue
            if args.exchangeable:
                r = exchangeable(args.first_seed + s, preset, args.minutes, models, args.model, args.exchangeable,
                                 args.jobs)
                said = "false alarms " + ", ".join(f"{100 * r['false_alarm'][str(c)]:.1f}% with {c}" for c in COUNTS)
            else:
                r = one(args.first_seed + s, preset, args.minutes, models, args.model, args.replicas, args.jobs,
                        args.tracking)
                said = "; ".join(f"{n} z = {z:+.1f}" for n, z in r["disagreements"]) or "no disagreement"
            done.append(r)
            write_jsonl(done_path, done)
            print(f"{preset} seed {r['seed']}: {said}", flush=True)
    table = exchangeable_summary(done) if args.exchangeable else summary(done)
    if args.exchangeable:
        false_alarm_figure(done, out / "false_alarms.png")
    text = "\n".join([f"# The calibrated check of the {args.model} model on effect-free logs", "", *table]) + "\n"
    atomic_write(out / "check_null.md", lambda f: f.write(text.encode()))
    print(text)


if __name__ == "__main__":
    main()
