"""Per-landmark bearing offsets of the real robots measured against Vicon, beside ``aibo diagnose``'s
``landmark_bearing_offset`` (when a report is given).

    python scripts/mrclam_bearing_offsets.py [DATA] [--robots 1,4,5] [--dt 0.1] [--report ROBOT=report.json ...]

DATA defaults to ../shared/data/mrclam7 (never copied into the repository). Per robot: the bearing residual of each
sighting at the Vicon pose of its frame's end (measured - predicted, wrapped; |residual| < 0.3 rad), its mean per
landmark (mrad) with its standard error, the same after a term c omega (the true turn rate, rad/s: a sensor time
offset) is regressed out, and both with their mean over the landmarks removed (sum 0, as the learner holds them).
With ``--report``, the report's whole-log offsets (``parameters_when_named``: the training half's) are printed
beside them with their correlation and RMS difference. Prints only.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from aibo_core.geometry import wrap
from aibo_core.mrclam import import_robot

OUTLIER_RAD = 0.3  # residuals beyond this are other robots or misread barcodes


def vicon_offsets(folder: Path, robot: int, dt: float) -> dict[str, np.ndarray | float]:
    """Per-landmark mean bearing residual at the Vicon poses (rad), its standard error, the sighting counts, the
    time offset c (s) of residual ~ a + c omega, and the per-landmark means after c omega is removed."""
    tr = import_robot(folder, robot, dt=dt)
    f = tr.sighting_frame
    pose = tr.pose[f + 1]
    omega = wrap(tr.pose[np.minimum(f + 2, tr.n_frames), 2] - tr.pose[f, 2]) / (2.0 * tr.dt)
    lm = tr.landmarks[tr.sighting_landmark]
    r = wrap(tr.sighting_value[:, 1] - wrap(np.arctan2(lm[:, 1] - pose[:, 1], lm[:, 0] - pose[:, 0]) - pose[:, 2]))
    ok = np.abs(r) < OUTLIER_RAD
    X = np.stack([np.ones(ok.sum()), omega[ok]], axis=1)
    c = float(np.linalg.lstsq(X, r[ok], rcond=None)[0][1])
    B, L = len(tr.landmarks), tr.sighting_landmark[ok]
    n = np.bincount(L, minlength=B)
    seen = n > 1

    def per_landmark(v: np.ndarray) -> np.ndarray:
        return np.where(seen, np.bincount(L, weights=v, minlength=B) / np.maximum(n, 1), np.nan)

    mean = per_landmark(r[ok])
    sd = np.sqrt(np.maximum(per_landmark(r[ok] ** 2) - mean**2, 0.0))
    return {"mean": mean, "se": sd / np.sqrt(np.maximum(n - 1, 1)), "n": n, "time_offset_s": c,
            "no_omega": per_landmark(r[ok] - c * omega[ok])}


def centred(x: np.ndarray) -> np.ndarray:
    """``x`` less its mean over the finite entries (the learner's sum-0 group)."""
    return x - np.nanmean(x)


def mrad(x: np.ndarray) -> str:
    return " ".join(f"{1e3 * v:+6.1f}" for v in x)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", nargs="?", default=str(Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "mrclam7"))
    ap.add_argument("--robots", default="1,4,5")
    ap.add_argument("--dt", type=float, default=0.1)
    ap.add_argument("--report", action="append", default=[], help="ROBOT=path of an aibo diagnose report.json")
    args = ap.parse_args()
    reports = dict(item.split("=", 1) for item in args.report)
    for robot in (int(r) for r in args.robots.split(",")):
        v = vicon_offsets(Path(args.data), robot, args.dt)
        print(f"robot {robot}: time offset {v['time_offset_s']:+.3f} s, common offset {1e3 * np.nanmean(v['mean']):+.1f} mrad")
        print(f"  Vicon, sum 0 (mrad):           {mrad(centred(v['mean']))}")
        print(f"  Vicon, c omega out, sum 0:     {mrad(centred(v['no_omega']))}")
        print(f"  standard error (mrad):         {mrad(v['se'])}")
        if str(robot) in reports:
            effect = [e for e in json.loads(Path(reports[str(robot)]).read_text())["effects"]
                      if e["name"] == "landmark_bearing_offset"]
            if not effect:
                print("  diagnose: landmark_bearing_offset not named")
                continue
            for label, key in (("whole log", "parameters"), ("training half", "parameters_when_named")):
                est = np.asarray(effect[0][key]["offset_rad"], float)
                ok = np.isfinite(v["mean"])
                ref = centred(v["mean"])
                print(f"  diagnose, {label:13s} (mrad): {mrad(est)}  (corr {np.corrcoef(est[ok], ref[ok])[0, 1]:+.2f}, "
                      f"RMS difference {1e3 * np.sqrt(np.mean((est[ok] - ref[ok]) ** 2)):.1f} mrad)")


if __name__ == "__main__":
    main()
