"""How often does the calibrated check disagree with a log its model is right about? Its threshold is set so that a
right model shows no disagreement in 95% of checks (``experiments.calibrated``: Bonferroni over the statistics,
Student t over the replicas); this measures it.

    python scripts/check_null.py [--seeds 50] [--first-seed 6000] [--presets aibo,paper-sim] [--minutes 5]
                                 [--replicas 8] [--jobs 2] [--out runs/check_null] [--table]

Blind simulated logs with no effect, ``--seeds`` per noise preset (interleaved, so a run stopped early covers both);
on each, the base model of ``aibo diagnose`` (``signatures_null.fitted_base``: the search's base fit on the training
half, outliers set aside, polished; cached in ``models/``) and the calibrated check of it (``predictive_check``, the
replicas' seed 0). Reported: per preset, the logs with any disagreement (target: at most 5%, with its exact 95%
upper bound), the count of disagreements per log, and which statistics disagreed. Resumable (``runs.jsonl``);
writes ``check_null.md``.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

from scipy import stats

sys.path.insert(0, str(Path(__file__).resolve().parent))
from signatures_null import fitted_base  # noqa: E402

from aibo_core.atomic import atomic_write, read_jsonl, write_jsonl  # noqa: E402
from aibo_core.trajectory import blind  # noqa: E402
from aibo_gym.collect import collect  # noqa: E402
from experiments.calibrated import predictive_check  # noqa: E402


def one(seed: int, preset: str, minutes: float, models: Path, replicas: int, jobs: int) -> dict:
    """One effect-free blind log: the check of its base model, (statistic, z) of every disagreement."""
    tr = blind(collect({"noise": preset, "effects": {}}, int(minutes * 60 * 30), seed=seed))
    base, logs = fitted_base(tr, models / f"{preset}-{seed}.json", refit=False)
    check = predictive_check(base, logs, replicas=replicas, seed=0, jobs=jobs)
    return {"seed": seed, "preset": preset, "minutes": minutes, "replicas": replicas, "statistics": len(check.names),
            "threshold": check.threshold, "failed_replicas": len(check.failed),
            "disagreements": [[n, z] for n, z in check.disagreements()]}


def upper_bound(k: int, n: int) -> float:
    """Exact (Clopper-Pearson) one-sided 95% upper bound of a rate seen k times in n."""
    return 1.0 if k >= n else float(stats.beta.ppf(0.95, k + 1, n - k))


def summary(done: list[dict]) -> list[str]:
    """The tables of the module docstring, as markdown lines."""
    lines = ["| preset | logs | with any disagreement | 95% upper bound | disagreements per log: 0 / 1 / 2+ | "
             "statistics that disagreed (times) |", "|---|---|---|---|---|---|"]
    for preset in sorted({r["preset"] for r in done}) + ["both"]:
        runs = [r for r in done if preset in ("both", r["preset"])]
        n, counts = len(runs), Counter(min(len(r["disagreements"]), 2) for r in runs)
        k = n - counts[0]
        which = Counter(name for r in runs for name, _ in r["disagreements"])
        lines.append(f"| {preset} | {n} | **{k}** ({100 * k / max(n, 1):.0f}%) | {100 * upper_bound(k, n):.1f}% | "
                     f"{counts[0]} / {counts[1]} / {counts[2]} | "
                     + "; ".join(f"{name} ({c})" for name, c in which.most_common()) + " |")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=50, help="effect-free logs per noise preset")
    ap.add_argument("--presets", default="aibo,paper-sim")
    ap.add_argument("--minutes", type=float, default=5.0)
    ap.add_argument("--first-seed", type=int, default=6000, help="the logs' seeds are this and the next --seeds - 1")
    ap.add_argument("--replicas", type=int, default=8)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default="runs/check_null")
    ap.add_argument("--table", action="store_true", help="print the table of the rows so far and stop")
    args = ap.parse_args()
    out = Path(args.out)
    models = out / "models"
    models.mkdir(parents=True, exist_ok=True)
    done_path = out / "runs.jsonl"
    done = read_jsonl(done_path)
    have = {(r["seed"], r["preset"]) for r in done}
    for s in range(0 if args.table else args.seeds):
        for preset in args.presets.split(","):
            if (args.first_seed + s, preset) in have:
                continue
            r = one(args.first_seed + s, preset, args.minutes, models, args.replicas, args.jobs)
            done.append(r)
            write_jsonl(done_path, done)
            said = "; ".join(f"{n} z = {z:+.1f}" for n, z in r["disagreements"]) or "no disagreement"
            print(f"{preset} seed {r['seed']}: {said}", flush=True)
    text = "\n".join(["# The calibrated check on effect-free logs", "", *summary(done)]) + "\n"
    atomic_write(out / "check_null.md", lambda f: f.write(text.encode()))
    print(text)


if __name__ == "__main__":
    main()
