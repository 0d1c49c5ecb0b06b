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
the floor, the floor at equal time per command (``equal``); two ratios: ``pose`` = bound / floor
(information lost to pose uncertainty, where sightings matter; also per component) and
``alloc`` = floor / equal (lost to unequal time per command); and ``range info``, the range
information of the log's sightings per frame: the sum of (closest range / true distance)^4 over
the frames (a height's distance error grows as d^2; 1 = a beacon at the closest range every
frame). The figure shows, per component and policy, the distribution of ``se`` / ``floor`` over
every parameter of every run.
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
    """Per component, the ratio EM standard error / odometry floor of every parameter (commands x
    runs) as boxes per policy, 5-minute and 15-minute logs side by side; 1 = the floor."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    policies = sorted({r["policy"] for r in runs})
    minutes = sorted({r["minutes"] for r in runs})
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.4), sharey=True)
    width = 0.8 / len(minutes)
    for c, ax in enumerate(axes):
        for j, m in enumerate(minutes):
            data = []
            for pol in policies:
                ratios = [r["se_rel"][:, c] / r["floor_rel"][:, c] for r in runs if r["policy"] == pol and r["minutes"] == m]
                v = np.concatenate(ratios) if ratios else np.array([np.nan])
                data.append(v[np.isfinite(v)])
            pos = np.arange(len(policies)) + (j - (len(minutes) - 1) / 2) * width
            box = ax.boxplot(data, positions=pos, widths=0.9 * width, patch_artist=True, showfliers=False,
                             medianprops={"color": "k"})
            for patch in box["boxes"]:
                patch.set_facecolor(colors[j % len(colors)])
                patch.set_alpha(0.6)
        ax.axhline(1.0, color="k", ls="--", lw=1)
        ax.set_xticks(np.arange(len(policies)), policies, rotation=20, fontsize=8)
        ax.set_title(f"{COMPONENTS[c]}: EM standard error / odometry floor")
        ax.grid(alpha=0.3, axis="y")
    for j, m in enumerate(minutes):
        axes[0].bar([0], [0], color=colors[j % len(colors)], alpha=0.6, label=f"{m:g}-minute logs")
    axes[0].plot([], [], "k--", lw=1, label="floor: poses known, slip only")
    axes[0].legend(fontsize=8, loc="upper right")
    axes[0].set_ylim(0, None)
    fig.suptitle("Where the information goes: per velocity parameter, how far above the odometry floor of its time held")
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
