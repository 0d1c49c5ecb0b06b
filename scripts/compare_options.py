"""Evidence for the EM defaults: the paper's recipe and each deviation, on several 15-minute logs.

    python scripts/compare_options.py [--seeds 11 12 13] [--noise paper-sim] [--json out.json]

For each seed: simulate a 15-minute random-balanced log, fit every variant from the paper's
start, and print the mean (and worst) error per variant, beside the oracle's. docs/results.md's
options table is this script's output.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from experiments.loop import fit_em, score, simulate
from learners.em.options import EMOptions
from learners.oracle import OracleLearner

VARIANTS = {
    "paper recipe, gate 13.8": EMOptions.paper(gate=13.8155),
    "paper recipe (gate 50)": EMOptions.paper(),
    "+ learned motion noise": EMOptions.paper(learn_motion_noise=True),
    "+ cubature sensor step": EMOptions(accel="none", min_improvement=0.1),
    "+ SQUAREM (default)": EMOptions(),
}
KEYS = ("vx_rel", "vy_rel", "vtheta_rel", "sigma_height_rel", "sigma_angle_rel", "sensor_rms_px")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[11, 12, 13])
    ap.add_argument("--noise", default="paper-sim", choices=["paper-sim", "aibo"])
    ap.add_argument("--steps", type=int, default=27000)
    ap.add_argument("--json", help="write all rows to this file")
    args = ap.parse_args()
    rows = []
    for seed in args.seeds:
        tr = simulate({"noise": args.noise}, args.steps, seed)
        rows.append({"seed": seed, "variant": "oracle (true poses)", "iterations": 1, "seconds": 0.0,
                     **score(OracleLearner().fit([tr]).params, [tr])})
        for name, opts in VARIANTS.items():
            t0 = time.perf_counter()
            res = fit_em([tr], EMOptions(**{**opts.__dict__, "seed": seed}))
            rows.append({"seed": seed, "variant": name, "iterations": res.iterations,
                         "seconds": time.perf_counter() - t0, "pruned": res.pruned_observations,
                         **score(res.params, [tr])})
            print(f"seed {seed} {name:26s} {res.iterations:5d} it  " +
                  "  ".join(f"{k}={rows[-1][k]:.4f}" for k in KEYS), flush=True)
    names = ["oracle (true poses)", *VARIANTS]
    print(f"\n{len(args.seeds)} seeds, {args.noise} noise, {args.steps} frames: mean (worst) over seeds\n")
    print("| variant | iterations | vx | vy | vtheta | sigma_h | sigma_a | sensor px |")
    print("|---|---|---|---|---|---|---|---|")
    for name in names:
        sel = [r for r in rows if r["variant"] == name]
        cells = [f"{np.mean([r['iterations'] for r in sel]):.0f}"]
        for k in KEYS:
            v = np.array([r[k] for r in sel])
            cells.append(f"{v.mean():.3f} ({v.max():.3f})" if k == "sensor_rms_px" else
                         f"{100 * v.mean():.2f}% ({100 * v.max():.2f}%)")
        print(f"| {name} | " + " | ".join(cells) + " |")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
