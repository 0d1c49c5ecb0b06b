"""Does the calibrated check's timing statistic see a driver that steers on the robot's pose, where the robot has no
timing error at all?

    python scripts/closed_loop_timing.py [--seeds 4,5,6,7] [--drivers waypoints,10,2] [--replicas 16] [--jobs 2]
                                         [--out runs/closed_loop_timing]

Per seed, a 5-minute ``WheeledRobot-v0`` log (random start, no effect: no lag, no response time) driven by each of
``--drivers``: ``waypoints``, the waypoint driver (``collect_wheeled``; its commands change on about a tenth of the
frames), or a number tau (s), the same path driven again by a driver that corrects every frame's command towards it on
the true pose with time constant tau (``collect_closed_loop``: every command answers the motion's own errors, as
MRCLAM's controllers' at 67 Hz). On each, ``aibo learn``'s model (its defaults; it finds no lag) and the calibrated
check of it, its replicas open loop (the default) and steered along the model's smoothed path (``tracking``, whose
loop's time constant is ``TRACKING_TAU_S``, 10 s): the z of "turn vs change of the commanded turn rate", the
statistics disagreeing, and the correlation of the true turn's error (the true heading change less the model-free
gain x the commanded one) with the command's change one frame later (``LATER``), which no causal response makes.

Resumable (OUT/rows.jsonl); OUT/table.md rewritten after each row. docs/results.md, "A driver that steers on its pose".
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from study import resume  # noqa: E402

from aibo_core.trajectory import Trajectory  # noqa: E402
from learners.discrepancy.signatures import CHANGE_OF  # noqa: E402

TIMING = f"turn (sigma) vs {CHANGE_OF['turn']} (strength)"  # the check's timing statistic
STEPS = 3000  # 5 minutes at 10 frames a second
LATER = 1  # frames: the command's change this long after the error's frame


def later_correlation(log: Trajectory, k: int = LATER) -> float:
    """The correlation of each frame's true turn error (the true heading change less the least-squares gain times the
    commanded turn) with the commanded turn rate's change ``k`` frames later."""
    turn = np.diff(np.unwrap(log.pose[:, 2]))[: len(log.controls)] / log.dt
    omega = log.controls[: len(turn), 1]
    error = turn - (omega @ turn) / (omega @ omega) * omega
    change = np.diff(omega, prepend=omega[0])
    return float(np.corrcoef(error[: len(error) - k], change[k:])[0, 1])


def row(key: dict, replicas: int, jobs: int) -> dict:
    from aibo_gym.collect_wheeled import collect_closed_loop, collect_wheeled
    from experiments.calibrated import predictive_check
    from learners.em.learner import EMLearner
    from learners.em.options import EMOptions

    config = {"start_pose": "random"}
    driver, seed = key["driver"], key["seed"]
    log = (collect_wheeled(config, STEPS, seed) if driver == "waypoints"
           else collect_closed_loop(config, STEPS, seed, float(driver)))
    model = EMLearner(EMOptions(seed=0, uncertainty=False)).fit([log]).params
    out = dict(key, lag_s=model.effect("actuation_lag").lag_s if model.effect("actuation_lag") else 0.0,
               changes=float(np.mean(np.diff(log.controls[:, 1]) != 0)), later=later_correlation(log))
    for name, tracking in (("open", False), ("tracked", True)):
        check = predictive_check(model, [log], replicas, 0, jobs, tracking=tracking)
        z = dict(zip(check.names, check.z))
        out[name] = {"timing_z": float(z[TIMING]), "disagree": [[n, float(v)] for n, v in check.disagreements()]}
    return out


def table(rows: list[dict]) -> str:
    lines = ["| driver | seed | commands changing | error vs the next change | lag found (s) | timing z: open loop / "
             "tracked | disagreeing: open loop / tracked |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        cells = [" ".join(f"{n.split(' (')[0]} {v:+.1f}" for n, v in r[k]["disagree"]) or "none"
                 for k in ("open", "tracked")]
        lines.append(f"| {r['driver']} | {r['seed']} | {r['changes']:.0%} | {r['later']:+.3f} | {r['lag_s']:g} | "
                     f"{r['open']['timing_z']:+.1f} / {r['tracked']['timing_z']:+.1f} | {cells[0]} / {cells[1]} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="4,5,6,7")
    ap.add_argument("--drivers", default="waypoints,10,2",
                    help="'waypoints' or a closed loop's time constant (s), comma-separated")
    ap.add_argument("--replicas", type=int, default=16)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default="runs/closed_loop_timing")
    args = ap.parse_args()
    keys = [{"driver": d, "seed": int(s)} for s in args.seeds.split(",") for d in args.drivers.split(",")]
    resume(Path(args.out), "rows.jsonl", keys, lambda k: row(k, args.replicas, args.jobs), table,
           lambda r, md: print(md.splitlines()[-1], flush=True))


if __name__ == "__main__":
    main()
