"""Are the residual signatures honest? On effect-free logs no signature should be "significant" more often than its
p-value says (``learners.discrepancy.signatures``).

    python scripts/signatures_null.py [--seeds 20] [--first-seed 6000] [--presets aibo,paper-sim] [--minutes 5]
                                      [--out runs/signatures] [--again] [--refit]

Blind simulated logs with no effect, ``--seeds`` per noise preset; on each, the base model of ``aibo diagnose`` (the
search's ``base_fit`` on the training half, outliers set aside, polished as the search does) and every signature of
it on the logs. Reported: per signature, the share of logs where its p < 0.001 and < 0.05 (expected 0.001 and 0.05
if the p-value is honest), and per preset, the logs with ANY signature at p < 0.001 (about 3% expected from ~30
signatures; target: at most 5% of the logs). Writes ``signatures.md`` (tables) beside the resumable ``runs.jsonl``;
the fitted base models are cached in ``models/`` (``--refit`` to ignore them), so that a change of the signatures is
measured again on the same fits in seconds.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from aibo_core.atomic import atomic_write, read_jsonl, write_jsonl
from aibo_core.trajectory import Trajectory, blind
from aibo_gym.collect import collect
from learners.discrepancy.fitting import SEARCH_PATIENCE, fit
from learners.discrepancy.search import base_and_outliers, drop_outliers
from learners.discrepancy.signatures import signatures
from learners.discrepancy.split import training_log
from learners.em.options import EMOptions
from learners.model.io import load_model, save_model
from learners.model.model import Model

LEVELS = (0.001, 0.05)


def fitted_base(tr: Trajectory, cache: Path, refit: bool) -> tuple[Model, list[Trajectory]]:
    """The base model ``aibo diagnose`` draws its signatures from (``search.search``'s first steps), and the log with
    its outliers set aside; the model read from ``cache`` when it is there (and not ``refit``)."""
    opts = EMOptions().comparable()
    if cache.exists() and not refit:
        base = load_model(cache)
        logs, _ = drop_outliers(base, [tr])
        return base, logs
    base, _, logs, _ = base_and_outliers([tr], opts, progress=lambda line: None)
    polish = replace(opts, gate=None, max_iter=min(opts.max_iter, 200), patience=min(opts.patience, SEARCH_PATIENCE))
    base = fit([training_log(t) for t in logs], base, polish)
    save_model(cache, base, {})
    return base, logs


def one(seed: int, preset: str, minutes: float, models: Path, refit: bool) -> dict:
    """One effect-free blind log: every signature of its base model, (residual, variable, p)."""
    tr = blind(collect({"noise": preset, "effects": {}}, int(minutes * 60 * 30), seed=seed))
    base, logs = fitted_base(tr, models / f"{preset}-{seed}.json", refit)
    sigs = signatures(base, logs)
    return {"seed": seed, "preset": preset, "minutes": minutes,
            "signatures": [[s.residual, s.variable, s.p_value] for s in sigs]}


def summary(done: list[dict]) -> list[str]:
    """The tables of the module docstring, as markdown lines."""
    lines = []
    for preset in sorted({r["preset"] for r in done}):
        runs = [r for r in done if r["preset"] == preset]
        n = len(runs)
        any_low = sum(any(p < LEVELS[0] for _, _, p in r["signatures"]) for r in runs)
        lines += [f"## {preset}: {n} effect-free logs of {runs[0]['minutes']:g} min", "",
                  f"logs with any signature at p < {LEVELS[0]}: **{any_low} of {n}**", "",
                  "| signature | p < 0.001 | p < 0.05 | median p |", "|---|---|---|---|"]
        keys = sorted({(a, b) for r in runs for a, b, _ in r["signatures"]})
        rows = []
        for a, b in keys:
            ps = np.array([p for r in runs for x, y, p in r["signatures"] if (x, y) == (a, b)])
            rows.append((np.mean(ps < LEVELS[0]), f"| {a} vs {b} | {np.sum(ps < LEVELS[0])} / {len(ps)} | "
                         f"{np.sum(ps < LEVELS[1])} / {len(ps)} | {np.median(ps):.2g} |"))
        lines += [row for _, row in sorted(rows, key=lambda t: -t[0])] + [""]
    return lines


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=20, help="effect-free logs per noise preset")
    ap.add_argument("--presets", default="aibo,paper-sim")
    ap.add_argument("--minutes", type=float, default=5.0)
    ap.add_argument("--first-seed", type=int, default=6000, help="the logs' seeds are this and the next --seeds - 1")
    ap.add_argument("--out", default="runs/signatures")
    ap.add_argument("--refit", action="store_true", help="fit the base models again (default: the cached ones)")
    ap.add_argument("--again", action="store_true", help="recompute every log's signatures (from the cached fits)")
    args = ap.parse_args()
    out = Path(args.out)
    models = out / "models"
    models.mkdir(parents=True, exist_ok=True)
    done_path = out / "runs.jsonl"
    done = [] if args.again else read_jsonl(done_path)
    have = {(r["seed"], r["preset"]) for r in done}
    for s in range(args.seeds):  # interleaved: a run stopped early covers both presets
        for preset in args.presets.split(","):
            if (args.first_seed + s, preset) in have:
                continue
            r = one(args.first_seed + s, preset, args.minutes, models, args.refit)
            done.append(r)
            write_jsonl(done_path, done)
            low = [f"{a} vs {b} p = {p:.1g}" for a, b, p in r["signatures"] if p < LEVELS[0]]
            print(f"{preset} seed {r['seed']}: {'; '.join(low) or 'nothing below 0.001'}", flush=True)
    text = "\n".join(["# Residual signatures on effect-free logs", "", *summary(done)]) + "\n"
    atomic_write(out / "signatures.md", lambda f: f.write(text.encode()))
    print(text)


if __name__ == "__main__":
    main()
