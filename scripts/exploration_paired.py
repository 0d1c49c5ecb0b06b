"""Paired comparison of exploration policies in an ``aibo experiment policies`` sweep: mean and
standard error over seeds of each policy's velocity error, and of its relative difference to
baselines on the same robot and seed.

    python scripts/exploration_paired.py SWEEP [--baselines random-balanced,informed] [--key vel_rel_mean]
        [--target random-balanced=-0.30,informed=-0.10] [--json FILE]

For each length and seed every policy walked the same robot (``robot_seed``), so the comparison
is paired: per seed s, d_s = e_policy / e_baseline - 1, and the table gives mean(d) +- std(d) /
sqrt(n) over the seeds both runs exist for (diverged runs kept: they are part of the policy's
risk). ``--key`` is a record key (default ``vel_rel_mean``: the mean of the vx, vy, vtheta errors
relative to each component's range; ``vxy`` is (vx + vy) / 2). ``--target`` names, per baseline,
the relative difference a policy must reach; the verdict lists which cells meet it (on the mean).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def value(rec: dict, key: str) -> float:
    if key == "vxy":
        return 0.5 * (rec["vx_rel"] + rec["vy_rel"])
    return float(rec[key])


def mean_se(x) -> tuple[float, float]:
    x = np.asarray(x, float)
    return float(x.mean()), float(x.std(ddof=1) / np.sqrt(len(x))) if len(x) > 1 else float("nan")


def compare(records: list[dict], baselines: list[str], key: str) -> list[dict]:
    by = {(r["policy"], r["minutes"], r["seed"]): value(r, key) for r in records}
    policies = list(dict.fromkeys(r["policy"] for r in records))
    minutes = sorted({r["minutes"] for r in records})
    rows = []
    for m in minutes:
        for p in policies:
            seeds = sorted(s for (q, mm, s) in by if q == p and mm == m)
            if not seeds:
                continue
            row = {"policy": p, "minutes": m, "n": len(seeds)}
            row["error"], row["error_se"] = mean_se([by[p, m, s] for s in seeds])
            for b in baselines:
                common = [s for s in seeds if (b, m, s) in by]
                if b == p or not common:
                    continue
                d = [by[p, m, s] / by[b, m, s] - 1.0 for s in common]
                row[f"vs {b}"], row[f"vs {b} se"] = mean_se(d)
                row[f"vs {b} n"] = len(common)
                row[f"vs {b} wins"] = int(sum(x < 0 for x in d))
            rows.append(row)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sweep", type=Path)
    ap.add_argument("--baselines", default="random-balanced,informed")
    ap.add_argument("--key", default="vel_rel_mean")
    ap.add_argument("--target", default="random-balanced=-0.30,informed=-0.10")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    records = [json.loads(line) for line in (args.sweep / "results.jsonl").read_text().splitlines() if line.strip()]
    baselines = [b for b in args.baselines.split(",") if b]
    target = {k: float(v) for k, v in (t.split("=") for t in args.target.split(",") if t)}
    rows = compare(records, baselines, args.key)
    print(f"| policy | min | seeds | {args.key} (mean ± se) | " + " | ".join(f"vs {b} (mean ± se; wins)" for b in baselines) + " |")
    print("|---|---|---|---|" + "---|" * len(baselines))
    for r in rows:
        cells = []
        for b in baselines:
            if f"vs {b}" in r:
                cells.append(f"{100 * r[f'vs {b}']:+.1f} ± {100 * r[f'vs {b} se']:.1f}% ({r[f'vs {b} wins']}/{r[f'vs {b} n']})")
            else:
                cells.append("")
        print(f"| {r['policy']} | {r['minutes']:g} | {r['n']} | {100 * r['error']:.2f} ± {100 * r['error_se']:.2f}% | "
              + " | ".join(cells) + " |")
    print()
    for r in rows:
        checks = [(b, r.get(f"vs {b}")) for b in target if f"vs {b}" in r]
        if len(checks) == len(target):
            ok = all(v <= target[b] for b, v in checks)
            print(f"{r['policy']} at {r['minutes']:g} min: target {'MET' if ok else 'not met'} ("
                  + ", ".join(f"{100 * v:+.1f}% vs {b}, needs <= {100 * target[b]:+.0f}%" for b, v in checks) + ")")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
