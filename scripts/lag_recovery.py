"""Does ``aibo learn`` recover a known time offset between commands and motion? Per MRCLAM Dataset 7 robot, the log
imported with its command timestamps shifted by s (``aibo import mrclam --lag S``: every command takes effect s
later in the log's time, so the lag the log shows is its own minus s) for each s, and the lag ``aibo learn``
estimates (with its 95% interval, ``learners.em.lag``) compared with the unshifted log's.

    python scripts/lag_recovery.py [DATA] [--out /tmp/lag_recovery] [--robots 1,2,3,4,5]
                                   [--shifts -0.3,-0.2,-0.1,-0.05,0.05,0.1,0.15]

DATA defaults to ../shared/data/mrclam7 (never copied into the repository). The recovered shift is lag(0) - lag(s)
(the truth: s); an interval covers when it holds lag(0) - s (the unshifted estimate stands for the robot's own lag,
so its error is shared by every row of a robot). Finished (robot, shift) rows are kept in OUT/rows.jsonl (a rerun
skips them); OUT/table.md is rewritten after each, with the mean error, the mean absolute error and the coverage.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from study import data_folder, mrclam_parser, resume, robots  # noqa: E402

from aibo_core.mrclam import import_robot  # noqa: E402
from learners.em.learner import EMLearner  # noqa: E402
from learners.em.options import EMOptions  # noqa: E402


def estimate(data: Path, robot: int, shift: float) -> dict:
    """``aibo learn``'s lag (defaults, no standard errors) on the robot's log with its commands shifted by ``shift``."""
    tr = import_robot(data, robot, lag_s=shift)
    info = EMLearner(EMOptions(uncertainty=False)).fit([tr]).info
    lag = info.get("lag_search") or {}
    return {"robot": robot, "shift_s": shift, "lag_s": lag.get("lag_s", 0.0), "interval_95": lag.get("interval_95"),
            "note": lag.get("interval_note", "")}


def table(rows: list[dict]) -> str:
    base = {r["robot"]: r["lag_s"] for r in rows if r["shift_s"] == 0.0}
    lines = ["| robot | shift s | lag s | 95% interval | recovered shift s | error ms | covers |", "|" + "---|" * 7]
    errors, covers = [], []
    for r in sorted(rows, key=lambda r: (r["robot"], r["shift_s"])):
        if r["shift_s"] == 0.0 or r["robot"] not in base:
            lines.append(f"| {r['robot']} | 0 | {r['lag_s']:.3f} | {_ci(r)} | | | |")
            continue
        rec = base[r["robot"]] - r["lag_s"]
        err = 1000.0 * (rec - r["shift_s"])
        target = base[r["robot"]] - r["shift_s"]
        cov = r["interval_95"] is not None and r["interval_95"][0] <= target <= r["interval_95"][1]
        errors.append(err)
        covers.append(cov)
        lines.append(f"| {r['robot']} | {r['shift_s']:+.2f} | {r['lag_s']:.3f} | {_ci(r)} | {rec:+.3f} | {err:+.1f} | "
                     f"{'yes' if cov else 'no'} |")
    if errors:
        lines.append(f"\nmean error {np.mean(errors):+.1f} ms, mean absolute error {np.mean(np.abs(errors)):.1f} ms, "
                     f"intervals cover {sum(covers)} of {len(covers)} ({100.0 * np.mean(covers):.0f}%)")
    return "\n".join(lines) + "\n"


def _ci(r: dict) -> str:
    return f"{r['interval_95'][0]:.3f}-{r['interval_95'][1]:.3f}" if r["interval_95"] else "-"


def main(argv=None) -> int:
    ap = mrclam_parser(__doc__, "/tmp/lag_recovery")
    ap.add_argument("--shifts", default="-0.3,-0.2,-0.1,-0.05,0.05,0.1,0.15",
                    help="comma-separated command time shifts, s (default -0.3,-0.2,-0.1,-0.05,0.05,0.1,0.15)")
    args = ap.parse_args(argv)
    data = data_folder("lag_recovery", args.data)
    if data is None:
        return 2
    shifts = [0.0] + [float(s) for s in args.shifts.split(",")]
    keys = [{"robot": r, "shift_s": s} for r in robots(args.robots) for s in shifts]
    rows = resume(Path(args.out), "rows.jsonl", keys, lambda k: estimate(data, k["robot"], k["shift_s"]), table,
                  lambda r, _: print(f"robot {r['robot']} shift {r['shift_s']:+.2f} s: lag {r['lag_s']:.3f} s {_ci(r)}",
                                     flush=True))
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
