"""A sensor away from the robot's origin: what ``aibo learn`` makes of its sightings imported as if it sat at the origin,
and with the importers' ``--sensor-pose``, on logs of a generator that shares nothing with ``aibo_gym``.

    python scripts/sensor_mount.py [--out /tmp/sensor_mount] [--seeds 1,2,3] [--minutes 10]

The generator (``write_drive``, NumPy only): a unicycle robot on a 30 x 20 m field with 12 landmarks at random
positions (ids 100-399), commands at about 20 Hz (jittered) held for 1-5 s, speed uniform in [0, top] m/s, turn rate
in [-1.2, 1.2] rad/s, steered back towards the middle within 3 m of the edge (a controller on the robot's pose); the
motion follows the commands 0.1 s late at 0.9 of their speed and 0.93 of their turn, with noise 5% + 0.01; a camera at
5 Hz (jittered) sees landmarks within 8 m and 0.8 rad of its axis with probability 0.7, range noise 0.05 m + 2%,
bearing noise 0.03 rad; truth at 100 Hz; times on the Unix clock. Two robots: top speed 0.3 m/s ("slow") and 1.5 m/s
("fast"). Mounts: the origin; 0.25 m ahead; (0.1, -0.08) m turned 0.2 rad.

Each (seed, robot, mount) is written as CSV files, imported by ``aibo import csv`` (with and without the mount's
``--sensor-pose``) and fitted by ``aibo learn`` with its defaults, as a user runs them. Scores against the truth:
the smoothed pose's RMS distance (mm) and the forward speed's RMS error over 1 s windows (mm/s;
``learners.scoring``). Rows kept in OUT/rows.jsonl (a rerun skips them); OUT/table.md rewritten after each.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from study import resume, run_aibo  # noqa: E402

from aibo_core import trajectory  # noqa: E402
from learners.model.io import load_model  # noqa: E402
from learners.scoring import pose_scores, velocity_scores  # noqa: E402

TOP_SPEED_M_S = {"slow": 0.3, "fast": 1.5}
MOUNTS = {"origin": (0.0, 0.0, 0.0), "ahead": (0.25, 0.0, 0.0), "side, turned": (0.1, -0.08, 0.2)}
FIELD_M = (30.0, 20.0)
STEP_S = 0.005  # the generator's integration step


def _wrap(a: np.ndarray | float) -> np.ndarray | float:
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _commands(rng: np.random.Generator, seconds: float, top: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(times s, speed m/s, turn rad/s): jittered 20 Hz messages of a command held for 1-5 s."""
    t = np.cumsum(rng.uniform(0.04, 0.06, int(seconds / 0.04) + 10))
    t = t[t < seconds]
    change = np.cumsum(rng.uniform(1.0, 5.0, int(seconds) + 10))
    k = np.searchsorted(change, t)
    return t, rng.uniform(0.0, top, len(change) + 1)[k], rng.uniform(-1.2, 1.2, len(change) + 1)[k]


def write_drive(folder: Path, seed: int, top: float, minutes: float, mount: tuple[float, float, float],
                delay_s: float = 0.0) -> None:
    """One log of the generator (module docstring) as ``aibo import csv``'s files in ``folder``; ``delay_s``: the
    camera's time stamps that much after the moment seen (negative: before it)."""
    rng = np.random.default_rng(seed)
    width, height = FIELD_M
    ids = rng.choice(np.arange(100, 400), 12, replace=False)
    marks = np.column_stack([rng.uniform(0, width, 12), rng.uniform(0, height, 12)])
    t0, seconds = 1.7e9 + rng.uniform(0, 1e6), minutes * 60.0
    cmd_t, speed, turn = _commands(rng, seconds, top)
    x = np.array([width / 2, height / 2, 0.0])
    truth, seen, history = [], [], []
    k, next_camera, lag = 0, 0.0, int(round(0.1 / STEP_S))
    for i in range(int(seconds / STEP_S)):
        t = i * STEP_S
        while k + 1 < len(cmd_t) and cmd_t[k + 1] <= t:
            k += 1
            if not (3 < x[0] < width - 3 and 3 < x[1] < height - 3):  # steer back: the commands answer the pose
                turn[k] = np.clip(2.0 * _wrap(np.arctan2(height / 2 - x[1], width / 2 - x[0]) - x[2]), -1.2, 1.2)
        history.append((speed[k], turn[k]))
        v, w = history[max(0, i - lag)]
        v = 0.9 * v + rng.normal(0, 0.05 * abs(v) + 0.01)
        w = 0.93 * w + rng.normal(0, 0.05 * abs(w) + 0.01)
        x = x + STEP_S * np.array([v * np.cos(x[2]), v * np.sin(x[2]), w])
        if i % 2 == 0:
            truth.append((t0 + t, x[0], x[1], _wrap(x[2])))
        if t >= next_camera:
            next_camera += 0.2 + rng.uniform(-0.01, 0.01)
            c, s = np.cos(x[2]), np.sin(x[2])
            sensor = x[:2] + [c * mount[0] - s * mount[1], s * mount[0] + c * mount[1]]
            d = marks - sensor
            r = np.hypot(d[:, 0], d[:, 1])
            b = _wrap(np.arctan2(d[:, 1], d[:, 0]) - x[2] - mount[2])
            for j in np.flatnonzero((r < 8.0) & (np.abs(b) < 0.8) & (rng.random(12) < 0.7)):
                seen.append((t0 + t + delay_s, ids[j], r[j] * (1 + rng.normal(0, 0.02)) + rng.normal(0, 0.05),
                             b[j] + rng.normal(0, 0.03)))
    folder.mkdir(parents=True, exist_ok=True)
    tables = {"commands": ("t,v_m_s,omega_rad_s", np.column_stack([t0 + cmd_t, speed, turn]), "%.6f"),
              "detections": ("t,id,range_m,bearing_rad", np.array(seen), ["%.6f", "%d", "%.5f", "%.5f"]),
              "landmarks": ("id,x_m,y_m", np.column_stack([ids, marks]), ["%d", "%.4f", "%.4f"]),
              "truth": ("t,x_m,y_m,theta_rad", np.array(truth), "%.6f")}
    for name, (header, rows, fmt) in tables.items():
        np.savetxt(folder / f"{name}.csv", rows, delimiter=",", header=header, comments="", fmt=fmt)


def run_row(out: Path, key: dict, minutes: float) -> dict:
    """One (seed, robot, mount, given) row: the log written (once per seed, robot and mount), imported, fitted, scored."""
    mount = MOUNTS[key["mount"]]
    name = f"s{key['seed']}_{key['robot']}_{key['mount'].replace(', ', '_')}"
    folder = out / name
    if not (folder / "truth.csv").exists():
        write_drive(folder, key["seed"], TOP_SPEED_M_S[key["robot"]], minutes, mount)
    stem = out / f"{name}_{'given' if key['given'] else 'not_given'}"
    pose_option = ["--sensor-pose", ",".join(f"{v:g}" for v in mount)] if key["given"] else []
    for args in (["import", "csv", str(folder), "--out", f"{stem}.npz", *pose_option],
                 ["learn", f"{stem}.npz", "--out", f"{stem}.json"]):
        seconds, done = run_aibo(args)
        if done.returncode:
            raise SystemExit(f"aibo {' '.join(args)}: {done.stderr.strip()}")
    log, model = trajectory.load(f"{stem}.npz"), load_model(f"{stem}.json")
    return {**key, "pose_mm": pose_scores(model, [log])["pose_rms"], "forward_mm_s": velocity_scores(model, [log])["vx_rms"],
            "learn_s": seconds}


def table(rows: list[dict]) -> str:
    lines = ["| seed | robot | sensor mount (m, m, rad) | --sensor-pose | pose RMS mm | forward RMS mm/s | learn s |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['seed']} | {r['robot']} | {r['mount']} {MOUNTS[r['mount']]} | {'given' if r['given'] else '-'} "
                     f"| {r['pose_mm']:.1f} | {r['forward_mm_s']:.2f} | {r['learn_s']:.0f} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="/tmp/sensor_mount")
    ap.add_argument("--seeds", default="1,2,3", help="comma-separated generator seeds (default 1,2,3)")
    ap.add_argument("--minutes", type=float, default=10.0, help="each log's length (default 10)")
    args = ap.parse_args()
    keys = [{"seed": int(s), "robot": robot, "mount": mount, "given": given}
            for s in args.seeds.split(",") for robot in TOP_SPEED_M_S for mount in MOUNTS
            for given in ((False,) if mount == "origin" else (False, True))]
    rows = resume(Path(args.out), "rows.jsonl", keys, lambda key: run_row(Path(args.out), key, args.minutes), table,
                  lambda row, md: print(md.splitlines()[-1], flush=True))
    print(table(rows))


if __name__ == "__main__":
    main()
