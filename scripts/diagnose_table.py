"""One blind log per effect of the catalogue, diagnosed with ``aibo diagnose`` (all candidates, the
calibrated simulator on): the table of effect, true parameters, what was named with its estimate,
gap before and after, calibrated-simulator disagreements before and after, and seconds.

    python scripts/diagnose_table.py [--minutes 10] [--seed 11] [--replicas 16] [--out runs/diagnose_table]

Logs: ``aibo`` noise preset, random-balanced policy; ``wall_contact`` with paths that leave the field
by 800 mm (the policy's ``margin_mm``), so that the walls are hit. Writes ``OUT/table.md`` and each
case's report folder; resumable (finished cases are kept in ``OUT/rows.jsonl``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from aibo.cli import DIAGNOSE_REPLICAS, main  # noqa: E402
from aibo.diagnose_report import short  # noqa: E402
from aibo_core.trajectory import blind, save  # noqa: E402
from aibo_gym.collect import collect  # noqa: E402

#: case -> (effects config, policy params); the strengths of tests/test_discrepancy.py
CASES: dict[str, tuple[dict, dict]] = {
    "floor_drift": ({"floor_drift": {"drift_mm_s": [15.0, -10.0]}}, {}),
    "velocity_fade": ({"velocity_fade": {"fade_per_min": 0.03}}, {}),
    "actuation_lag": ({"actuation_lag": {"lag_s": 0.2}}, {}),
    "off_center_shrink": ({"off_center_shrink": {"k": 0.3}}, {}),
    "distance_dependent_noise": ({"distance_dependent_noise": {"exponent": 1.0}}, {}),
    "beacon_height_scale": ({"beacon_height_scale": {"scale": [1.08, 0.94, 1.04, 0.95]}}, {}),
    "false_sightings": ({"false_sightings": {"rate": 0.1}}, {}),
    "wall_contact": ({}, {"margin_mm": -800.0}),
    "angle_bias": ({"angle_bias": {"bias_rad": 0.05}}, {}),
    "none": ({}, {}),
}


def run_case(name: str, out: Path, minutes: float, seed: int, replicas: int) -> dict:
    effects, policy_params = CASES[name]
    tr = collect({"noise": "aibo", "effects": effects}, int(minutes * 1800), seed=seed, policy_params=policy_params)
    log = out / f"{name}.npz"
    save(blind(tr), log)
    t0 = time.perf_counter()
    code = main(["diagnose", str(log), "--out", str(out / name), "--replicas", str(replicas), "--seed", "0"])
    seconds = time.perf_counter() - t0
    report = json.loads((out / name / "report.json").read_text()) if code == 0 else {}
    cal = report.get("calibrated_simulation", {})
    return {
        "case": name, "true": short(next(iter(effects.values()), {})) if effects else "",
        "named": "; ".join(f"{e['name']} {short(e['parameters'])}" for e in report.get("effects", [])) or "none",
        "not_identifiable": [c["name"] for c in report.get("candidates", []) if not c["identifiable"]],
        "gap_before": report.get("gap_before"), "gap_after": report.get("gap_after"),
        "disagree_before": len(cal.get("before", {}).get("disagreements", [])),
        "disagree_after": len(cal.get("after", {}).get("disagreements", [])),
        "worst_before": (cal.get("before", {}).get("disagreements") or [{"statistic": ""}])[0]["statistic"],
        "seconds": seconds, "exit": code,
    }


def table(rows: list[dict]) -> str:
    lines = ["| hidden effect | true | named, estimate | gap before -> after | calibrated sim: disagreements before -> after "
             "(strongest before) | seconds |", "|---|---|---|---|---|---|"]
    for r in rows:
        gap = f"{r['gap_before']:.3f} -> {r['gap_after']:.3f}" if r["gap_before"] is not None else "failed"
        hidden = sorted(set(r["not_identifiable"]))
        named = r["named"] + (f" (not identifiable: {', '.join(hidden)})" if hidden else "")
        lines.append(f"| `{r['case']}` | {r['true']} | {named} | {gap} | {r['disagree_before']} -> {r['disagree_after']} "
                     f"({r['worst_before']}) | {r['seconds']:.0f} |")
    return "\n".join(lines) + "\n"


def main_script() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--replicas", type=int, default=DIAGNOSE_REPLICAS)
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--out", default="runs/diagnose_table")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    done_file = out / "rows.jsonl"
    done = {r["case"]: r for r in map(json.loads, done_file.read_text().splitlines())} if done_file.exists() else {}
    for name in args.cases.split(","):
        if name not in done:
            done[name] = run_case(name, out, args.minutes, args.seed, args.replicas)
            with done_file.open("a") as f:
                f.write(json.dumps(done[name]) + "\n")
    text = table([done[n] for n in args.cases.split(",")])
    (out / "table.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main_script()
