"""Where an exploration log's information goes: per velocity parameter, EM's standard error
against the odometry floor of the frames its command was held.

    python scripts/exploration_spectrum.py SWEEP[=SUFFIX] [SWEEP ...] [--png FILE] [--json FILE]

SWEEP: folders of ``aibo experiment policies`` (``results.jsonl`` and ``runs/``); ``=SUFFIX`` is
appended to that sweep's policy labels (two sweeps of one policy with other parameters). For every run,
per command a and component c (vx mm/s, vy mm/s, vtheta rad/s):

* ``se``: EM's standard error of the learned velocity (``model.json``, Fisher information of the
  innovations: what the log determines);
* ``floor``: slip_std_c / (dt sqrt(N_a)), N_a the frames command a was held: the standard error
  if every pose were known exactly (only the per-frame slip left), the most any policy's
  sightings can give for that time held.

Per policy and length it prints the mean over runs of (RMS over commands, relative to each
component's range, averaged over the three components): the actual error, EM's bound (``se``),
the floor, the floor at equal time per command (``equal``), and two ratios: ``pose`` = bound /
floor (information lost to pose uncertainty: where sightings matter; also per component) and ``alloc`` = floor /
equal (lost to unequal time per command), and ``range info``: the range information of the
log's sightings per frame, sum of (closest range / true distance)^4 over frames (a height's
distance error grows as d^2: 1 = a beacon at the closest range every frame). The figure plots ``se`` / range against N_a per
parameter (policies as colours) with the floor line.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from aibo_core import trajectory
from aibo_gym.config import make_config
from aibo_gym.robot import true_velocities

COMPONENTS = ("vx", "vy", "vtheta")


def run_spectrum(sweep: Path, record: dict, suffix: str = "") -> dict:
    """Per-parameter numbers of one run (see the module docstring)."""
    cfg = make_config(record["spec"]["env"])
    model = json.loads((sweep / record["model"]).read_text())
    se = np.array(model["info"]["standard_errors"]["action_model.velocities"], dtype=float)
    log = trajectory.load(sweep / record["log"])
    frames = np.bincount(log.actions, minlength=len(se)).astype(float)
    true = true_velocities(cfg)
    span = true.max(axis=0) - true.min(axis=0)
    slip = np.asarray(cfg["slip_std"], float) / cfg["dt"]  # per-frame slip as a velocity, mm/s, mm/s, rad/s
    used = frames > 0
    pose = log.pose[log.sighting_frame + 1]  # the true pose at each sighting (a simulated log)
    beacon = np.asarray(log.landmarks, float)[log.sighting_landmark]
    d = np.hypot(beacon[:, 0] - pose[:, 0], beacon[:, 1] - pose[:, 1])
    range_info = float(((cfg["range_mm"][0] / d) ** 4).sum() / log.n_frames)
    floor = slip[None, :] / np.sqrt(np.where(used, frames, np.nan))[:, None]
    equal = slip / np.sqrt(frames.sum() / len(frames))
    rms = lambda x: np.sqrt(np.nanmean(x[used] ** 2, axis=0)) / span  # noqa: E731
    return {"policy": record["policy"] + suffix, "minutes": record["minutes"], "seed": record["seed"],
            "error": record["vel_rel_mean"], "bound": float(rms(se).mean()), "floor": float(rms(floor).mean()),
            "pose_c": rms(se) / rms(floor), "range_info": range_info,
            "equal": float((equal / span).mean()), "frames": frames, "se_rel": se / span, "floor_rel": floor / span}


def load(sweeps: list[str]) -> list[dict]:
    """Every run of the sweeps (``PATH`` or ``PATH=SUFFIX``)."""
    out = []
    for arg in sweeps:
        path, _, suffix = arg.partition("=")
        sweep = Path(path)
        for line in (sweep / "results.jsonl").read_text().splitlines():
            rec = json.loads(line)
            if rec.get("model") and rec.get("log"):
                out.append(run_spectrum(sweep, rec, suffix))
    return out


def summarize(runs: list[dict]) -> list[dict]:
    rows: dict[tuple, list[dict]] = {}
    for r in runs:
        rows.setdefault((r["policy"], r["minutes"]), []).append(r)
    out = []
    for (pol, m), rs in sorted(rows.items(), key=lambda kv: (kv[0][1], kv[0][0])):
        mean = {k: float(np.mean([r[k] for r in rs])) for k in ("error", "bound", "floor", "equal", "range_info")}
        pose_c = np.mean([r["pose_c"] for r in rs], axis=0)
        out.append({"policy": pol, "minutes": m, "n": len(rs), **mean, "pose": mean["bound"] / mean["floor"],
                    "pose_vx": float(pose_c[0]), "pose_vy": float(pose_c[1]), "pose_vtheta": float(pose_c[2]),
                    "alloc": mean["floor"] / mean["equal"]})
    return out


def plot(runs: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    policies = sorted({r["policy"] for r in runs})
    colors = dict(zip(policies, plt.rcParams["axes.prop_cycle"].by_key()["color"]))
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.4), sharey=True)
    for c, ax in enumerate(axes):
        for r in runs:
            marker = "o" if r["minutes"] <= 5 else "^"
            ax.scatter(r["frames"], 100 * r["se_rel"][:, c], s=6, alpha=0.35, color=colors[r["policy"]], marker=marker)
        lo = max(1.0, min(r["frames"][r["frames"] > 0].min() for r in runs))
        n = np.geomspace(lo, max(r["frames"].max() for r in runs), 50)
        ref = runs[0]
        k = np.nanmedian(ref["floor_rel"][:, c] * np.sqrt(ref["frames"]))  # floor = k / sqrt(N)
        ax.plot(n, 100 * k / np.sqrt(n), "k--", lw=1.2, label="odometry floor (poses known)")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("frames the command was held")
        ax.set_title(f"{COMPONENTS[c]}: EM standard error / range (%)")
        ax.grid(alpha=0.3, which="both")
    for pol in policies:
        axes[0].scatter([], [], color=colors[pol], label=pol)
    axes[0].scatter([], [], color="gray", marker="o", label="5 min")
    axes[0].scatter([], [], color="gray", marker="^", label="15 min")
    axes[0].legend(fontsize=7, loc="lower left")
    fig.suptitle("Where the information goes: per velocity parameter, EM's standard error vs time held")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sweeps", nargs="+", help="sweep folders, each PATH or PATH=SUFFIX")
    ap.add_argument("--png", type=Path, default=None)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    runs = load(args.sweeps)
    rows = summarize(runs)
    print("| policy | min | runs | error | EM bound | floor | equal-time floor | pose (bound/floor) | vx, vy, vtheta | "
          "alloc (floor/equal) | range info |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['policy']} | {r['minutes']:g} | {r['n']} | {100 * r['error']:.2f}% | {100 * r['bound']:.2f}% | "
              f"{100 * r['floor']:.2f}% | {100 * r['equal']:.2f}% | {r['pose']:.2f} | "
              f"{r['pose_vx']:.2f}, {r['pose_vy']:.2f}, {r['pose_vtheta']:.2f} | {r['alloc']:.2f} | {r['range_info']:.3f} |")
    if args.png:
        plot(runs, args.png)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
