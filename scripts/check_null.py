"""How often does the calibrated check disagree with a log its model is right about? Its threshold is set so that a
right model shows no disagreement in 95% of checks (``experiments.calibrated``: Bonferroni over the statistics,
Student t over the replicas); this measures it.

    python scripts/check_null.py [--seeds 50] [--first-seed 6000] [--presets aibo,paper-sim] [--minutes 5]
                                 [--model base|learn] [--replicas 8] [--jobs 2] [--out DIR] [--table]

Blind simulated logs with no effect, ``--seeds`` per noise preset (interleaved, so a run stopped early covers both);
on each, a model of it and the calibrated check of that model (``predictive_check``, the replicas' seed 0). The model
(``--model``): ``base``, the base model of ``aibo diagnose`` (``signatures_null.fitted_base``: the search's base fit on
the training half, outliers set aside, polished; cached in ``models/``), what its check "before the named effects"
checks; ``learn``, ``aibo learn``'s fit of the whole log (its default options; outliers set aside), the start of
``aibo diagnose``'s final fit, which writes the model the check "after" checks. Reported: per preset, the logs with
any disagreement (target: at most 5%, with its exact 95% upper bound), the count of disagreements per log, and which
statistics disagreed. Resumable (``runs.jsonl`` in
``--out``, default ``runs/check_null/MODEL``); writes ``check_null.md`` there.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diagnose_power import upper95  # noqa: E402
from signatures_null import fitted_base  # noqa: E402

from aibo_core.atomic import atomic_write, read_jsonl, write_jsonl  # noqa: E402
from aibo_core.trajectory import Trajectory, blind  # noqa: E402
from aibo_gym.collect import collect  # noqa: E402
from experiments.calibrated import predictive_check  # noqa: E402
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


def one(seed: int, preset: str, minutes: float, models: Path, which: str, replicas: int, jobs: int) -> dict:
    """One effect-free blind log: the check of its ``which`` model, (statistic, z) of every disagreement."""
    tr = blind(collect({"noise": preset, "effects": {}}, int(minutes * 60 * 30), seed=seed))
    model, logs = fitted(tr, which, models / f"{preset}-{seed}.json")
    check = predictive_check(model, logs, replicas=replicas, seed=0, jobs=jobs)
    return {"seed": seed, "preset": preset, "minutes": minutes, "model": which, "replicas": replicas,
            "statistics": len(check.names),
            "threshold": check.threshold, "failed_replicas": len(check.failed),
            "disagreements": [[n, z] for n, z in check.disagreements()]}


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
    ap.add_argument("--replicas", type=int, default=8)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default=None, help="default runs/check_null/MODEL")
    ap.add_argument("--table", action="store_true", help="print the table of the rows so far and stop")
    args = ap.parse_args()
    out = Path(args.out or f"runs/check_null/{args.model}")
    models = out / "models"
    models.mkdir(parents=True, exist_ok=True)
    done_path = out / "runs.jsonl"
    done = read_jsonl(done_path)
    have = {(r["seed"], r["preset"]) for r in done}
    for s in range(0 if args.table else args.seeds):
        for preset in args.presets.split(","):
            if (args.first_seed + s, preset) in have:
                continue
            r = one(args.first_seed + s, preset, args.minutes, models, args.model, args.replicas, args.jobs)
            done.append(r)
            write_jsonl(done_path, done)
            said = "; ".join(f"{n} z = {z:+.1f}" for n, z in r["disagreements"]) or "no disagreement"
            print(f"{preset} seed {r['seed']}: {said}", flush=True)
    text = "\n".join([f"# The calibrated check of the {args.model} model on effect-free logs", "", *summary(done)]) + "\n"
    atomic_write(out / "check_null.md", lambda f: f.write(text.encode()))
    print(text)


if __name__ == "__main__":
    main()
