"""False-alarm rate and detection power of the discrepancy workflow (``aibo diagnose``'s search).

    python scripts/diagnose_power.py [--seeds 20] [--presets aibo,paper-sim] [--wall-seeds 0] [--power-seeds 5]
                                     [--minutes 10] [--effects a,b] [--out runs/power]

Blind simulated logs, every effect of the catalogue a candidate:
- effect-free logs, ``--seeds`` per noise preset, and ``--wall-seeds`` per preset whose random walk leaves the
  field by 800 mm (the robot meets the walls: ``wall_contact`` is there and is the one right name). A false alarm
  is a log with any other named effect (family-wise; target: at most 5%), with its exact (Clopper-Pearson) 95%
  upper bound; ``angle_bias`` named anywhere is counted apart (it is not identifiable);
- each effect at three strengths over ``--power-seeds`` seeds (``aibo`` preset; detection = the effect named
  first).
Writes ``power.json``, ``power.md`` (tables) and ``power.png``; resumable (finished runs are kept in
``runs.jsonl``).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from aibo_core.atomic import atomic_write, read_jsonl, write_jsonl
from aibo_core.trajectory import blind
from aibo_gym.collect import collect
from learners.discrepancy.search import search
from learners.em.options import EMOptions
from learners.model.effects import EFFECT_MODELS

STRENGTHS = {
    "floor_drift": [{"drift_mm_s": [s, 0.0]} for s in (3.0, 6.0, 12.0)],
    "velocity_fade": [{"fade_per_min": f} for f in (0.005, 0.01, 0.02)],
    "actuation_lag": [{"lag_s": t} for t in (0.05, 0.1, 0.2)],
    "off_center_shrink": [{"k": k} for k in (0.05, 0.1, 0.2)],
    "distance_dependent_noise": [{"exponent": e} for e in (0.25, 0.5, 1.0)],
    "beacon_height_scale": [{"scale": [1 + s, 1 - s, 1 + s / 2, 1 - s / 2]} for s in (0.01, 0.02, 0.04)],
}


WALL_MARGIN_MM = -800.0  # the random walk's margin to the walls: negative, it leaves the field (tests/test_discrepancy_more)


def one(effect: str | None, params: dict | None, seed: int, minutes: float, preset: str = "aibo",
        walls: bool = False) -> dict:
    """One blind log, diagnosed with every candidate: what was named and how long it took (s)."""
    config = {"noise": preset, "effects": {effect: params} if effect else {}}
    policy = {"margin_mm": WALL_MARGIN_MM} if walls else None
    tr = blind(collect(config, int(minutes * 60 * 30), seed=seed, policy_params=policy))
    t0 = time.perf_counter()
    found = search([tr], sorted(EFFECT_MODELS), EMOptions(), jobs=2, progress=lambda s: None)
    named = [c.name for c in found["named"]]
    return {"effect": effect or "none", "params": params, "seed": seed, "preset": preset, "walls": walls,
            "named": named, "detected": bool(named) and named[0] == (effect or ""),
            "seconds": time.perf_counter() - t0}


def false_alarm(r: dict) -> bool:
    """An effect-free log with a named effect that is not there (``wall_contact`` is there when the walls are met)."""
    allowed = {"wall_contact"} if r.get("walls") else set()
    return bool(set(r["named"]) - allowed)


def upper95(k: int, n: int) -> float:
    """Exact (Clopper-Pearson) one-sided 95% upper bound on a rate seen k times in n."""
    from scipy import stats

    return 1.0 if k >= n else float(stats.beta.ppf(0.95, k + 1, n - k))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=20, help="effect-free logs per noise preset")
    ap.add_argument("--presets", default="aibo", help="noise presets of the effect-free logs (aibo,paper-sim)")
    ap.add_argument("--wall-seeds", type=int, default=0, help="effect-free logs per preset that meet the walls")
    ap.add_argument("--power-seeds", type=int, default=5)
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--effects", default=",".join(STRENGTHS))
    ap.add_argument("--out", default="runs/power")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    done_path = out / "runs.jsonl"
    done = read_jsonl(done_path)
    key = {(r["effect"], json.dumps(r["params"]), r["seed"], r.get("preset", "aibo"), r.get("walls", False))
           for r in done}
    jobs = []
    # interleaved (seed by seed: each preset without, then with walls), so that a run stopped early covers every
    # group of the false-alarm table
    for s in range(max(args.seeds, args.wall_seeds)):
        for preset in args.presets.split(","):
            jobs += [(None, None, 1000 + s, preset, False)] if s < args.seeds else []
            jobs += [(None, None, 3000 + s, preset, True)] if s < args.wall_seeds else []
    for e in filter(None, args.effects.split(",")):
        jobs += [(e, p, 2000 + s, "aibo", False) for p in STRENGTHS[e] for s in range(args.power_seeds)]
    for effect, params, seed, preset, walls in jobs:
        if (effect or "none", json.dumps(params), seed, preset, walls) in key:
            continue
        r = one(effect, params, seed, args.minutes, preset, walls)
        done.append(r)
        write_jsonl(done_path, done)
        print(f"{r['effect']:26s} {json.dumps(r['params'])!s:45s} {preset}{' walls' if walls else ''} seed {seed}: "
              f"named {r['named']} ({r['seconds']:.0f} s)", flush=True)
    summarize(done, out)


def summarize(done: list[dict], out: Path) -> None:
    none = [r for r in done if r["effect"] == "none"]
    alarms = sum(false_alarm(r) for r in none)
    fa = alarms / len(none) if none else float("nan")
    lines = [f"False alarms: {alarms} of {len(none)} effect-free logs ({fa:.1%}; 95% upper bound "
             f"{upper95(alarms, len(none)):.1%}); angle_bias named in {sum('angle_bias' in r['named'] for r in none)}.",
             "", "| noise preset | walls met | logs | false alarms | 95% upper bound | named (count) |",
             "|---|---|---|---|---|---|"]
    groups = sorted({(r.get("preset", "aibo"), bool(r.get("walls"))) for r in none})
    for preset, walls in groups:
        rs = [r for r in none if (r.get("preset", "aibo"), bool(r.get("walls"))) == (preset, walls)]
        k = sum(false_alarm(r) for r in rs)
        counts = {}
        for r in rs:
            for n in r["named"]:
                counts[n] = counts.get(n, 0) + 1
        lines.append(f"| {preset} | {'yes' if walls else 'no'} | {len(rs)} | {k} ({k / len(rs):.0%}) | "
                     f"{upper95(k, len(rs)):.0%} | {', '.join(f'{n} {c}' for n, c in sorted(counts.items())) or '-'} |")
    lines += ["", "| effect | strength | detected | runs |", "|---|---|---|---|"]
    power = {}
    for e in STRENGTHS:
        for p in STRENGTHS[e]:
            rs = [r for r in done if r["effect"] == e and r["params"] == p]
            if rs:
                rate = float(np.mean([r["detected"] for r in rs]))
                power.setdefault(e, []).append((p, rate, len(rs)))
                lines.append(f"| {e} | {json.dumps(p)} | {rate:.0%} | {len(rs)} |")
    text = "\n".join(lines) + "\n"
    atomic_write(out / "power.md", lambda f: f.write(text.encode()))
    summary = json.dumps({"false_alarm_rate": fa, "false_alarm_upper95": upper95(alarms, len(none)) if none else None,
                          "n_none": len(none), "power": power}, indent=1)
    atomic_write(out / "power.json", lambda f: f.write(summary.encode()))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4))
    for e, rows in power.items():
        ax.plot([1, 2, 3][: len(rows)], [r for _, r, _ in rows], marker="o", label=e)
    ax.axhline(fa, color="k", ls=":", label=f"false alarms ({fa:.0%})")
    ax.set_xticks([1, 2, 3], ["weak", "medium", "strong"])
    ax.set_ylabel("detection rate")
    ax.set_ylim(-0.05, 1.05)
    ax.legend(fontsize=7)
    ax.set_title("aibo diagnose: detection power against strength")
    fig.tight_layout()
    fig.savefig(out / "power.png", dpi=110)
    print(text)


if __name__ == "__main__":
    main()
