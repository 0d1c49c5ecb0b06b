"""False-alarm rate and detection power of the discrepancy workflow (``aibo diagnose``'s search).

    python scripts/diagnose_power.py [--seeds 20] [--power-seeds 5] [--minutes 10] [--out runs/power]

Blind simulated logs (``aibo`` noise preset): with no effect, over ``--seeds`` seeds (a false alarm is
any named effect; target: at most 5%), and for each effect at three strengths over ``--power-seeds``
seeds (detection = the effect named first). Writes ``power.json``, ``power.md`` (tables) and
``power.png``; resumable (finished runs are kept in ``runs.jsonl``).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from aibo_core.atomic import atomic_write
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


def one(effect: str | None, params: dict | None, seed: int, minutes: float) -> dict:
    config = {"noise": "aibo", "effects": {effect: params} if effect else {}}
    tr = blind(collect(config, int(minutes * 60 * 30), seed=seed))
    t0 = time.perf_counter()
    found = search([tr], sorted(EFFECT_MODELS), EMOptions(), jobs=2, progress=lambda s: None)
    named = [c.name for c in found["named"]]
    return {"effect": effect or "none", "params": params, "seed": seed, "named": named,
            "detected": bool(named) and named[0] == (effect or ""), "seconds": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--power-seeds", type=int, default=5)
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--effects", default=",".join(STRENGTHS))
    ap.add_argument("--out", default="runs/power")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    done_path = out / "runs.jsonl"
    done = [json.loads(line) for line in done_path.read_text().splitlines()] if done_path.exists() else []
    key = {(r["effect"], json.dumps(r["params"]), r["seed"]) for r in done}
    jobs = [(None, None, 1000 + s) for s in range(args.seeds)]
    for e in args.effects.split(","):
        jobs += [(e, p, 2000 + s) for p in STRENGTHS[e] for s in range(args.power_seeds)]
    for effect, params, seed in jobs:
        if (effect or "none", json.dumps(params), seed) in key:
            continue
        r = one(effect, params, seed, args.minutes)
        done.append(r)
        text = "".join(json.dumps(x) + "\n" for x in done)
        atomic_write(done_path, lambda f: f.write(text.encode()))
        print(f"{r['effect']:26s} {json.dumps(r['params'])!s:45s} seed {seed}: named {r['named']} ({r['seconds']:.0f} s)",
              flush=True)
    summarize(done, out)


def summarize(done: list[dict], out: Path) -> None:
    none = [r for r in done if r["effect"] == "none"]
    fa = float(np.mean([bool(r["named"]) for r in none])) if none else float("nan")
    lines = [f"False alarms: {sum(bool(r['named']) for r in none)} of {len(none)} effect-free logs ({fa:.0%}).", "",
             "| effect | strength | detected | runs |", "|---|---|---|---|"]
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
    summary = json.dumps({"false_alarm_rate": fa, "n_none": len(none), "power": power}, indent=1)
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
