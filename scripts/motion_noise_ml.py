"""Why `floor_drift`'s intervals fall short on short `aibo` logs: the motion noise at the likelihood's maximum.

    python scripts/motion_noise_ml.py --one 8058            # one effect-free 5-minute log: the noise, three ways
    python scripts/motion_noise_ml.py [--logs 50] [--out runs/motion-noise-ml]   # the drift's intervals, two ways

``--one SEED``: an effect-free 5-minute blind `aibo` log (true position noise 3 mm per frame in x and y, variance 9):
the position noise's variance (mm^2) and the log-likelihood of ``aibo learn``'s fit (its early stop), of EM continued
to the likelihood's maximum (0.1 nat, patience 50), of EM with the noise held at the truth, and of EM with the 40
commands' velocities held at the truth (the table M-step returning them; a scratch hook, only here).

The study: the calibration study's `aibo` logs of `floor_drift` at 12 mm/s (log i even, seed 8000 + i, blind, 5
minutes), each fitted from ``aibo learn``'s model with the drift added, EM to the maximum with the polish (the final
fit's stop rule), once with the motion noise learned (maximum likelihood) and once held at the truth; the drift's
Fisher standard errors from each fit; the coverage of their 95% intervals and the spread of the estimates over the
mean standard error. Resumable (OUT/rows.jsonl). docs/results.md, "The motion noise at the likelihood's maximum".
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from study import resume  # noqa: E402

TRUE_COV = np.diag([9.0, 9.0, 4e-4])  # the `aibo` preset's slip: 3 mm, 3 mm, 0.02 rad per frame
DRIFT = [12.0, 0.0]  # mm/s, the calibration study's strength


def _log(seed: int, drift: list[float] | None):
    from aibo_core.trajectory import blind
    from aibo_gym.collect import collect

    effects = {"floor_drift": {"drift_mm_s": drift}} if drift else {}
    full = collect({"noise": "aibo", "effects": effects}, 9000, seed=seed)
    return full, blind(full)


def one(seed: int) -> None:
    """``--one``: the noise of one effect-free log, three ways (module docstring)."""
    import learners.inference.kernels as kernels
    from learners.discrepancy.fitting import train_loglik
    from learners.em.learner import EMLearner
    from learners.em.options import EMOptions

    full, tr = _log(seed, None)
    strict = replace(EMOptions(seed=0).comparable(), patience=50, uncertainty=False)
    learned = EMLearner(EMOptions(seed=0)).fit([tr]).params
    true_w = np.asarray(full.meta["truth"]["velocities"], float) * tr.dt
    fits = {"aibo learn (its early stop)": learned,
            "EM to the likelihood's maximum": EMLearner(strict).fit([tr], init=learned).params,
            "the noise held at the truth": EMLearner(replace(strict, learn_motion_noise=False)).fit(
                [tr], init=learned.with_(action=replace(learned.action, cov=TRUE_COV))).params}
    means = kernels.table_means_compiled
    kernels.table_means_compiled = lambda commands, mu_star, weights: true_w.copy()  # velocities held at the truth
    try:
        fits["the velocities held at the truth"] = EMLearner(strict).fit(
            [tr], init=learned.with_(action=replace(learned.action, weights=true_w))).params
    finally:
        kernels.table_means_compiled = means
    for name, m in fits.items():
        var = np.diag(np.asarray(m.action.cov))[:2]
        print(f"{name:35s} position noise variance {var[0]:6.2f} / {var[1]:6.2f} mm^2   log-likelihood "
              f"{train_loglik(m, [tr]):9.2f}")


def drift_row(key: dict[str, Any]) -> dict[str, Any]:
    """One log of the study: the drift's estimate and standard error with the noise learned and held at the truth."""
    from learners.em.learner import EMLearner
    from learners.em.options import EMOptions
    from learners.model.catalogue import FloorDrift

    _, tr = _log(8000 + key["log"], DRIFT)
    start = EMLearner(EMOptions(seed=0)).fit([tr]).params.with_effect(FloorDrift(np.zeros(2)))
    opts = replace(EMOptions(seed=0).comparable(), patience=50, polish=True)
    row = dict(key)
    for name, o, init in (("ml", opts, start), ("truth", replace(opts, learn_motion_noise=False),
                                                 start.with_(action=replace(start.action, cov=TRUE_COV)))):
        r = EMLearner(o).fit([tr], init=init)
        row[name] = {"drift": r.params.effect("floor_drift").drift_mm_s.tolist(),
                     "se": r.info["standard_errors"]["effects.floor_drift.drift_mm_s"],
                     "noise_var": np.diag(np.asarray(r.params.action.cov))[:2].tolist()}
    return row


def table(rows: list[dict[str, Any]]) -> str:
    """Per way of fitting the noise, along / across the drift: the 95% Wald intervals' coverage, spread / SE and the
    mean SE (``calibration.summary``, the calibration study's own), and the position noise's median variance."""
    from calibration import Z95, summary

    lines = ["| motion noise | logs | coverage along / across the drift | spread / SE | mean SE (mm/s) | "
             "position noise variance, median (mm^2) |", "|---|---|---|---|---|---|"]
    for name, label in (("ml", "learned (maximum likelihood)"), ("truth", "held at the truth (9)")):
        s = []
        for j in range(2):
            values, ses = [r[name]["drift"][j] for r in rows], [r[name]["se"][j] for r in rows]
            s.append(summary(values, ses, [[v - Z95 * e, v + Z95 * e] for v, e in zip(values, ses)], DRIFT[j]))
        var = np.median([r[name]["noise_var"] for r in rows], axis=0)
        lines.append(f"| {label} | {len(rows)} | {s[0]['coverage']:.0%} / {s[1]['coverage']:.0%} | "
                     f"{s[0]['spread_ratio']:.2f} / {s[1]['spread_ratio']:.2f} | {s[0]['se']:.2f} / {s[1]['se']:.2f} | "
                     f"{var[0]:.2f} / {var[1]:.2f} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--one", type=int, default=None, metavar="SEED", help="one effect-free log, the noise three ways")
    ap.add_argument("--logs", type=int, default=50, help="the calibration study's logs 0 .. 2 x LOGS - 2, even")
    ap.add_argument("--out", default="runs/motion-noise-ml")
    args = ap.parse_args()
    if args.one is not None:
        one(args.one)
        return
    keys = [{"log": i} for i in range(0, 2 * args.logs, 2)]
    rows = resume(Path(args.out), "rows.jsonl", keys, drift_row, table,
                  lambda r, md: print(f"log {r['log']}: ml {np.round(r['ml']['drift'], 2)} +- {np.round(r['ml']['se'], 2)}, "
                                      f"truth {np.round(r['truth']['drift'], 2)} +- {np.round(r['truth']['se'], 2)}", flush=True))
    print(table(rows))


if __name__ == "__main__":
    main()
