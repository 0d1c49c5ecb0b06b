"""The real robots' ranges against Vicon: is the range the distance (the base model's held curve), or has it a scale
and an offset of its own?

    python scripts/mrclam_range_scale.py [DATA] [--robots 1,2,3,4,5] [--dt 0.1]

DATA defaults to ../shared/data/mrclam7 (never copied into the repository). Per robot: each sighting's distance d
(mm) and bearing phi (rad) at the Vicon pose of its frame's end, the least-squares fit of the measured range r = a d
(1 - k phi^2) + b (the base model holds a = 1, b = 0 and fits k: docs/results.md, "A range is depth"), the sightings
within ``OUTLIER_REL`` of the distance only, and the median of r / (d (1 - ``K_HELD`` phi^2)) in five distance bins
of equal counts. Prints only.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from aibo_core.geometry import wrap  # noqa: E402
from aibo_core.mrclam import import_robot  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from study import DATA, data_folder, robots  # noqa: E402

OUTLIER_REL = 0.3  # ranges further than this share from the distance are other robots or misread barcodes
K_HELD = 0.42  # the shrink the base model fits on these robots (0.40-0.44, README)
BINS = 5


def range_fit(folder: Path, robot: int, dt: float) -> dict:
    """{"n", "a", "k", "b_mm", "bins": [(d_lo_m, d_hi_m, median ratio)]} of ``robot`` (module docstring)."""
    tr = import_robot(folder, robot, dt=dt)
    pose = tr.pose[np.minimum(tr.sighting_frame + 1, tr.n_frames)]
    lm = tr.landmarks[tr.sighting_landmark]
    d = np.hypot(lm[:, 0] - pose[:, 0], lm[:, 1] - pose[:, 1])
    phi = wrap(np.arctan2(lm[:, 1] - pose[:, 1], lm[:, 0] - pose[:, 0]) - pose[:, 2])
    return range_curve(d, phi, tr.sighting_value[:, 0])


def range_curve(d: np.ndarray, phi: np.ndarray, r: np.ndarray) -> dict:
    """:func:`range_fit`'s record from the sightings' distances d (mm), bearings phi (rad) and ranges r (mm)."""
    ok = np.isfinite(r) & (np.abs(r / d - 1.0) < OUTLIER_REL)
    d, phi, r = d[ok], phi[ok], r[ok]
    (a, ak, b), *_ = np.linalg.lstsq(np.stack([d, -d * phi ** 2, np.ones_like(d)], axis=1), r, rcond=None)
    ratio = r / (d * (1.0 - K_HELD * phi ** 2))
    edges = np.quantile(d, np.linspace(0.0, 1.0, BINS + 1))
    bins = [(lo / 1000, hi / 1000, float(np.median(ratio[(d >= lo) & (d <= hi)]))) for lo, hi in zip(edges[:-1], edges[1:])]
    return {"n": int(ok.sum()), "a": float(a), "k": float(ak / a), "b_mm": float(b), "bins": bins}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default=str(DATA))
    ap.add_argument("--robots", default="1,2,3,4,5", help="comma-separated robot numbers (default 1,2,3,4,5)")
    ap.add_argument("--dt", type=float, default=0.1, help="the import's frame period (s)")
    args = ap.parse_args()
    folder = data_folder(__file__, args.data)
    if folder is None:
        return 1
    print(f"| robot | sightings | r = a d (1 - k phi^2) + b | median r / (d (1 - {K_HELD} phi^2)) by distance |\n"
          "|---|---|---|---|")
    for robot in robots(args.robots):
        f = range_fit(folder, robot, args.dt)
        print(f"| {robot} | {f['n']} | a {f['a']:.4f}, k {f['k']:.3f}, b {f['b_mm']:+.0f} mm | "
              + ", ".join(f"{lo:.1f}-{hi:.1f} m {m:.3f}" for lo, hi, m in f["bins"]) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
