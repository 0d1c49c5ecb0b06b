"""An effect outside the catalogue: does ``aibo diagnose``'s search force a catalogue name on it, and do the residual
signatures show what it is?

    python scripts/none_of_the_above.py [--seeds 5] [--minutes 5] [--grade 0.15] [--out runs/none_of_the_above]

The effect, a sloped floor (``experiments.outside_catalogue.SlopedFloor``, registered in the simulator by this
script only, never in the learners' catalogue): the walking speed x (1 + grade cos(heading - downhill)). Per seed: a
blind ``aibo`` preset log, the search with every candidate (as ``scripts/diagnose_power.py``), what it named and the
strongest residual signatures of its final model (``learners.discrepancy.signatures``), and the search's final
"none of the above" check (``learners.model.probes``). Right: nothing named and ``speed_vs_heading`` significant,
i.e. reported unexplained.
Resumable (``runs.jsonl``); writes ``summary.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from aibo_core.atomic import atomic_write, read_jsonl, write_jsonl  # noqa: E402
from aibo_core.trajectory import blind  # noqa: E402
from aibo_gym.collect import collect  # noqa: E402
from aibo_gym.effects import register_effect  # noqa: E402
from experiments.outside_catalogue import SlopedFloor  # noqa: E402
from learners.discrepancy.search import search  # noqa: E402
from learners.discrepancy.signatures import signatures  # noqa: E402
from learners.em.options import EMOptions  # noqa: E402
from learners.model.effects import EFFECT_MODELS  # noqa: E402

register_effect(SlopedFloor)  # for this script only: never in the catalogue


def one(seed: int, minutes: float, grade: float) -> dict:
    config = {"noise": "aibo", "effects": {"sloped_floor": {"grade": grade, "downhill_rad": 0.5}}}
    tr = blind(collect(config, int(minutes * 60 * 30), seed=seed))
    t0 = time.perf_counter()
    found = search([tr], sorted(EFFECT_MODELS), EMOptions(), jobs=2, progress=lambda s: None)
    sig = signatures(found["model"], found["logs"])[:3]
    probes = {c.name: {"gain_train": c.gain_train, "gain_heldout": c.gain_heldout, "p_value": c.p_value,
                       "coef": np.asarray(c.parameters.get("coef", [])).tolist(), "significant": c.significant}
              for c in found["probes"]}
    return {"seed": seed, "grade": grade, "named": [c.name for c in found["named"]],
            "unexplained": [n for n, c in probes.items() if c["significant"]], "probes": probes,
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
    right = [r for r in rows if not r["named"] and "speed_vs_heading" in r.get("unexplained", [])]
    lines = [f"Sloped floor (grade {args.grade}, not in the catalogue), {len(rows)} blind {args.minutes:g}-minute logs: "
             f"nothing named and reported unexplained as a speed that depends on the heading (``speed_vs_heading``) "
             f"in {len(right)}.", "",
             "| seed | named | none of the above (probe: train gain, held-out gain, p, coef) | strongest signatures of the "
             "final model | s |", "|---|---|---|---|---|"]
    lines += [f"| {r['seed']} | {', '.join(r['named']) or 'none'} | "
              + "; ".join(f"{'**' if c['significant'] else ''}{n}{'**' if c['significant'] else ''} +{c['gain_train']:.1f}, "
                          f"{c['gain_heldout']:+.1f}, {c['p_value']:.2g}, {np.round(c['coef'], 3).tolist()}"
                          for n, c in r.get("probes", {}).items())
              + f" | {'; '.join(r['strongest'])} | {r['seconds']:.0f} |" for r in rows]
    summary = "\n".join(lines) + "\n"
    atomic_write(out / "summary.md", lambda f: f.write(summary.encode()))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
