"""The range curve held at the distance against the curve freed from the held fit, on the real robots: whole logs and
halves they were not fitted to.

    python scripts/mrclam_range_curve.py [DATA] [--robots 1,2,3,4,5]

DATA defaults to ../shared/data/mrclam7 (never copied into the repository). Per robot, on the whole log and on each
half: ``aibo learn --range-curve held``'s fit (the range curve held at range = distance, its shrink fitted) and the
same log fitted again from that model with the curve free (``range_curve="free"``, one start: the two commands
``aibo learn LOG --range-curve held --out held.json`` and ``aibo learn LOG --range-curve free --init held.json``;
since 2026-11-29 ``aibo learn``'s default, ``--range-curve freed``, does both in one). Scored against
Vicon: the whole-log fits on the whole log (forward speed, turn rate over 1 s windows, smoothed pose RMS); the
halves' fits on the other half (forward speed, turn rate, and the motion gap at 5 s, as ``scripts/mrclam_crossval.py``
scores them: the half's gross outliers judged by the held fit and set aside once for both). The free curve's range at
1 and at 5 m (straight ahead). Prints a table.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from aibo_core.mrclam import import_robot  # noqa: E402
from learners.em.learner import EMLearner  # noqa: E402
from learners.em.options import EMOptions  # noqa: E402
from learners.scoring import pose_scores, velocity_scores  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mrclam_crossval import half_scores, halves, set_aside  # noqa: E402
from study import DATA, data_folder, robots  # noqa: E402

HELD = EMOptions(seed=0, uncertainty=False, range_curve="held")
#: the second fit: from the held fit, the curve free; one start and no searches (they ran in the first)
FREED = replace(HELD, range_curve="free", starts=1, alias_search=False, lag_search=False)


def fits(log) -> tuple:
    """(the held fit's model, the freed fit's model) on ``log``."""
    held = EMLearner(HELD).fit([log]).params
    return held, EMLearner(FREED).fit([log], init=held).params


def curve_at(model, d_mm: float) -> float:
    """The model's range (mm) of a landmark ``d_mm`` straight ahead."""
    return float(model.sensor.mean(np.array([d_mm]))[0])


def scores(model, test, clean) -> dict:
    """Forward speed and turn rate against Vicon on ``test``, and the smoothed pose's RMS (``clean`` None: the log it
    was fitted on) or the motion gap at 5 s on ``clean`` (a half it was not fitted to, ``mrclam_crossval.set_aside``)."""
    if clean is None:
        s = velocity_scores(model, [test])
        return {"vx_rms": s["vx_rms"], "vtheta_rms": s["vtheta_rms"], "last": pose_scores(model, [test])["pose_rms"]}
    s = half_scores(model, test, clean)
    return {**s, "last": s["motion_gap"]["5"]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default=str(DATA))
    ap.add_argument("--robots", default="1,2,3,4,5", help="comma-separated robot numbers (default 1,2,3,4,5)")
    args = ap.parse_args()
    folder = data_folder(__file__, args.data)
    if folder is None:
        return 1
    print("| robot | fitted on -> scored on | forward mm/s: held / freed | turn rad/s: held / freed | pose mm or motion gap "
          "5 s: held / freed | freed curve at 1 m, 5 m (mm) |\n|---|---|---|---|---|---|")
    for robot in robots(args.robots):
        whole = import_robot(folder, robot)
        first, second = halves(folder, robot)
        for label, fit_log, test, is_whole in (("whole -> whole", whole, whole, True),
                                               ("first -> second", first, second, False),
                                               ("second -> first", second, first, False)):
            held, freed = fits(fit_log)
            clean = None if is_whole else set_aside(held, test)[0]  # judged by the held fit, for both
            a, b = scores(held, test, clean), scores(freed, test, clean)
            digits = 0 if is_whole else 2
            print(f"| {robot} | {label} | {a['vx_rms']:.2f} / {b['vx_rms']:.2f} | {a['vtheta_rms']:.4f} / "
                  f"{b['vtheta_rms']:.4f} | {a['last']:.{digits}f} / {b['last']:.{digits}f} | "
                  f"{curve_at(freed, 1000.0):.0f}, {curve_at(freed, 5000.0):.0f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
