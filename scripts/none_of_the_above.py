"""An effect outside the catalogue: does ``aibo diagnose``'s search force a catalogue name on it, and do the residual
signatures show what it is?

    python scripts/none_of_the_above.py [--seeds 5] [--minutes 5] [--grade 0.15] [--out runs/none_of_the_above]

The effect, a sloped floor (``SlopedFloor``, registered in the simulator by this script only, never in the
learners' catalogue): the walking speed is multiplied by 1 + grade cos(heading - downhill), faster downhill and
slower uphill; the robot's own slip and the sensor are unchanged. No catalogue effect is this: ``floor_drift`` adds
a constant world-frame velocity whatever the command, ``velocity_fade`` shrinks the speed with time. Per seed: a
blind ``aibo`` preset log, the search with every candidate (as ``scripts/diagnose_power.py``), what it named and the
strongest residual signatures of its final model (``learners.discrepancy.signatures``). Right: nothing named (or only
what is there, e.g. ``wall_contact`` if the walls were met) and a heading signature among the strongest three.
Resumable (``runs.jsonl``); writes ``summary.md``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from aibo_core.atomic import atomic_write, read_jsonl, write_jsonl  # noqa: E402
from aibo_core.trajectory import blind  # noqa: E402
from aibo_gym.collect import collect  # noqa: E402
from aibo_gym.context import Frame, Motion  # noqa: E402
from aibo_gym.effects import Effect, register_effect  # noqa: E402
from learners.discrepancy.search import search  # noqa: E402
from learners.discrepancy.signatures import signatures  # noqa: E402
from learners.em.options import EMOptions  # noqa: E402
from learners.model.effects import EFFECT_MODELS  # noqa: E402


@register_effect
class SlopedFloor(Effect):
    """Walking speed x (1 + ``grade`` cos(heading - ``downhill_rad``)): faster downhill, slower uphill (not in the
    learners' catalogue)."""

    name = "sloped_floor"
    defaults = {"grade": 0.0, "downhill_rad": 0.0}
    bounds = {"grade": (0.0, 0.9)}

    def motion(self, m: Motion, frame: Frame) -> Motion:
        factor = 1.0 + self.params["grade"] * math.cos(frame.pose_before[2] - self.params["downhill_rad"])
        m.set_velocity(m.velocity * np.array([factor, factor, 1.0]), frame.dt)
        return m


def one(seed: int, minutes: float, grade: float) -> dict:
    config = {"noise": "aibo", "effects": {"sloped_floor": {"grade": grade, "downhill_rad": 0.5}}}
    tr = blind(collect(config, int(minutes * 60 * 30), seed=seed))
    t0 = time.perf_counter()
    found = search([tr], sorted(EFFECT_MODELS), EMOptions(), jobs=2, progress=lambda s: None)
    sig = signatures(found["model"], found["logs"])[:3]
    return {"seed": seed, "grade": grade, "named": [c.name for c in found["named"]],
            "strongest": [f"{s.residual} vs {s.variable} (p = {s.p_value:.2g})" for s in sig],
            "heading_shown": any("heading" in s.variable for s in sig), "seconds": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--minutes", type=float, default=5.0)
    ap.add_argument("--grade", type=float, default=0.15)
    ap.add_argument("--out", default="runs/none_of_the_above")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "runs.jsonl"
    done = read_jsonl(path)
    for seed in range(4000, 4000 + args.seeds):
        if any(r["seed"] == seed and r["grade"] == args.grade for r in done):
            continue
        done.append(one(seed, args.minutes, args.grade))
        print(json.dumps(done[-1]), flush=True)
        write_jsonl(path, done)
    rows = [r for r in done if r["grade"] == args.grade]
    right = [r for r in rows if not r["named"] and r["heading_shown"]]
    lines = [f"Sloped floor (grade {args.grade}, not in the catalogue), {len(rows)} blind {args.minutes:g}-minute logs: "
             f"nothing named and a heading signature among the strongest three in {len(right)}.", "",
             "| seed | named | strongest signatures of the final model | s |", "|---|---|---|---|"]
    lines += [f"| {r['seed']} | {', '.join(r['named']) or 'none'} | {'; '.join(r['strongest'])} | {r['seconds']:.0f} |"
              for r in rows]
    summary = "\n".join(lines) + "\n"
    atomic_write(out / "summary.md", lambda f: f.write(summary.encode()))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
