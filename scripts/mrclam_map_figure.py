"""Where an MRCLAM robot's sightings put the landmarks ``aibo learn``'s map check names: the map, the robot's smoothed
path under the model fitted on the map as given (``--no-map-repair``), and each named landmark's sightings placed
from that path (range along the bearing), beside where the map puts it.

    python scripts/mrclam_map_figure.py DATA [--robot 1] [--out docs/img/mrclam1_map_check.png]

DATA: an MRCLAM dataset folder (its ground truth is not needed); docs/results.md, "Landmarks where the map does not put
them", shows Dataset 1's robot 1.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from study import run_aibo  # noqa: E402

from aibo_core import trajectory  # noqa: E402
from aibo_core.mrclam import import_robot  # noqa: E402
from learners.model.io import load_model  # noqa: E402
from learners.scoring import smoothed_poses  # noqa: E402

COLOURS = ("tab:red", "tab:blue", "tab:green", "tab:purple")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data")
    ap.add_argument("--robot", type=int, default=1)
    ap.add_argument("--out", default="docs/img/mrclam1_map_check.png")
    args = ap.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tr = import_robot(args.data, args.robot)
    with tempfile.TemporaryDirectory() as tmp:
        log, model_path = Path(tmp) / "log.npz", Path(tmp) / "model.json"
        trajectory.save(tr, log)
        _, done = run_aibo(["learn", str(log), "--out", str(model_path), "--no-resume", "--no-map-repair"])
        if done.returncode != 0:
            print(done.stderr.strip().splitlines()[-1], file=sys.stderr)
            return 1
        model, info = load_model(model_path), json.loads(model_path.read_text())["info"]
    (mu,), _ = smoothed_poses(model, [tr])
    fig, ax = plt.subplots(figsize=(6.2, 8.0))
    ax.plot(mu[:, 0] / 1e3, mu[:, 1] / 1e3, color="0.8", lw=0.5, label="smoothed path (map as given)")
    ax.scatter(*(tr.landmarks / 1e3).T, marker="s", color="k", s=25, zorder=3)
    for lm, (x, y) in enumerate(tr.landmarks / 1e3):
        ax.annotate(str(lm), (x, y), xytext=(4, 4), textcoords="offset points", fontsize=8)
    pose = mu[tr.sighting_frame + 1]
    for colour, d in zip(COLOURS, info.get("map_check", [])):
        mine = tr.sighting_landmark == d["landmark"]
        p, r, b = pose[mine], tr.sighting_value[mine, 0], tr.sighting_value[mine, 1]
        seen = p[:, :2] + r[:, None] * np.stack([np.cos(p[:, 2] + b), np.sin(p[:, 2] + b)], axis=1)
        ax.scatter(*(seen / 1e3).T, s=3, color=colour, alpha=0.35,
                   label=f"landmark {d['landmark']}'s {int(mine.sum())} sightings, placed from the path")
        mx, my = np.array(d["map_xy"]) / 1e3
        ax.scatter([mx], [my], marker="s", s=90, facecolors="none", edgecolors=colour, lw=2, zorder=4)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    named = ", ".join(str(d["landmark"]) for d in info.get("map_check", [])) or "none"
    ax.set_title(f"{Path(args.data).name}, robot {args.robot}: landmarks named by the map check: {named}\n"
                 "(squares: the map; an open square: a named landmark's map position)", fontsize=9)
    ax.legend(loc="upper left", fontsize=7, markerscale=3)
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
