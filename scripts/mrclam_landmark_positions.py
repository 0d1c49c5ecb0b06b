"""Are the real robots' per-landmark errors map errors? Each landmark's position offset fitted against Vicon, robot by
robot, and whether the robots agree on it.

    python scripts/mrclam_landmark_positions.py [DATA] [--robots 1,2,3,4,5] [--dt 0.1]

DATA defaults to ../shared/data/mrclam7 (never copied into the repository). At the Vicon pose when each sighting was
made (``learners.scoring.truth_at_sightings``; sightings in the ground truth's gaps left out): the range residual
(measured - true distance to the mapped landmark, mm; a cubic in the distance removed: the range curve) and the bearing
residual (wrapped, rad; its mean removed), each in its own standard deviation; sightings with |bearing residual| >=
0.3 rad or |range residual| >= 500 mm are left out (other robots, misread barcodes).

A landmark truly at its mapped position + delta (mm, world frame) shifts the range by -u . delta and the bearing by
u_perp . delta / r (u the unit vector from the robot to the landmark): a term that changes with the viewing direction,
unlike a per-landmark range bias or bearing offset. Per robot and landmark (at least 30 sightings): delta by least
squares beside a range bias and a bearing offset of its own, its standard errors clustered by 10 s blocks (the
errors persist over a pass), and the share of the residual variance it explains beyond the bias and offset. A map
error is the same for every robot: per landmark seen by two robots or more, the chi-square of "one delta for all"
(2 (k - 1) degrees of freedom) and its p-value. Also per robot: a camera mounted off the tracked centre (a
robot-frame offset (forward, left) mm, the same for every landmark) and its share. Prints only.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy import stats

from aibo_core.geometry import wrap
from aibo_core.mrclam import import_robot
from learners.scoring import truth_at_sightings

OUTLIER_RAD, OUTLIER_MM = 0.3, 500.0
MIN_SIGHTINGS = 30
BLOCK_S = 10.0  # the standard errors' clusters (s)


def residuals(folder: Path, robot: int, dt: float) -> dict[str, np.ndarray]:
    """Per kept sighting: range and bearing residuals at the Vicon pose in their own sd units (``rr``, ``rb``), their
    sds (``sr`` mm, ``sb`` rad), the distance (mm), the world direction to the landmark and the robot-frame bearing
    (rad), the landmark and the time (s)."""
    tr = import_robot(folder, robot, dt=dt)
    known, pose = truth_at_sightings(tr)
    d = tr.landmarks[tr.sighting_landmark, :2] - pose[:, :2]
    dist, psi = np.hypot(d[:, 0], d[:, 1]), np.arctan2(d[:, 1], d[:, 0])
    bearing = wrap(psi - pose[:, 2])
    rr, rb = tr.sighting_value[:, 0] - dist, wrap(tr.sighting_value[:, 1] - bearing)
    ok = known & (np.abs(rb) < OUTLIER_RAD) & (np.abs(rr) < OUTLIER_MM)
    curve = np.vander(dist[ok] / 1000.0, 4)
    rr = rr[ok] - curve @ np.linalg.lstsq(curve, rr[ok], rcond=None)[0]
    rb = rb[ok] - rb[ok].mean()
    return {"rr": rr / rr.std(), "rb": rb / rb.std(), "sr": rr.std(), "sb": rb.std(), "dist": dist[ok], "psi": psi[ok],
            "bearing": bearing[ok], "landmark": tr.sighting_landmark[ok], "time": tr.sighting_frame[ok] * tr.dt}


def clustered_fit(a: np.ndarray, y: np.ndarray, block: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Least squares y ~ a x: (x, its covariance clustered by ``block``, the residual sum of squares)."""
    x = np.linalg.lstsq(a, y, rcond=None)[0]
    res = y - a @ x
    bread = np.linalg.inv(a.T @ a)
    scores = np.array([a[block == b].T @ res[block == b] for b in np.unique(block)])
    return x, bread @ (scores.T @ scores) @ bread, float(res @ res)


def landmark_offsets(r: dict[str, np.ndarray]) -> tuple[dict[int, tuple[np.ndarray, np.ndarray]], float, float]:
    """Per landmark: (delta (mm), its covariance); the share of the variance the biases and offsets explain, and the
    share the position offsets explain beyond them."""
    out, total, by_bias, by_delta = {}, 0.0, 0.0, 0.0
    for lm in np.unique(r["landmark"]):
        m = r["landmark"] == lm
        n = int(m.sum())
        if n < MIN_SIGHTINGS:
            continue
        u = np.stack([np.cos(r["psi"][m]), np.sin(r["psi"][m])], axis=1)
        a = np.zeros((2 * n, 4))
        a[:n, 0], a[n:, 1] = 1.0 / r["sr"], 1.0 / r["sb"]
        a[:n, 2:] = -u / r["sr"]
        a[n:, 2:] = np.stack([-u[:, 1], u[:, 0]], axis=1) / r["dist"][m, None] / r["sb"]
        y = np.r_[r["rr"][m], r["rb"][m]]
        block = np.r_[r["time"][m], r["time"][m]] // BLOCK_S
        x, cov, rss = clustered_fit(a, y, block)
        rss_bias = clustered_fit(a[:, :2], y, block)[2]
        total, by_bias, by_delta = total + y @ y, by_bias + y @ y - rss_bias, by_delta + rss_bias - rss
        out[int(lm)] = (x[2:], cov[2:, 2:])
    return out, by_bias / total, by_delta / total


def camera_offset(r: dict[str, np.ndarray]) -> tuple[np.ndarray, float]:
    """A robot-frame camera offset (forward, left) (mm) and the share of the variance it explains."""
    b = r["bearing"]
    a = np.r_[np.stack([-np.cos(b), -np.sin(b)], axis=1) / r["sr"],
              np.stack([np.sin(b), -np.cos(b)], axis=1) / r["dist"][:, None] / r["sb"]]
    y = np.r_[r["rr"], r["rb"]]
    x, _, rss = clustered_fit(a, y, np.r_[r["time"], r["time"]] // BLOCK_S)
    return x, 1.0 - rss / float(y @ y)


def agreement(fits: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, float, float]:
    """The robots' deltas of one landmark pooled (inverse-covariance weights): (pooled delta, chi-square of "one
    delta for all", its p-value)."""
    info = [np.linalg.inv(c) for _, c in fits]
    pooled = np.linalg.solve(sum(info), sum(w @ x for (x, _), w in zip(fits, info)))
    chi2 = float(sum((x - pooled) @ w @ (x - pooled) for (x, _), w in zip(fits, info)))
    return pooled, chi2, float(stats.chi2.sf(chi2, 2 * (len(fits) - 1)))


def cell(fit: tuple[np.ndarray, np.ndarray] | None) -> str:
    """One robot's delta of one landmark with its standard errors, or blank where it saw the landmark too little."""
    if fit is None:
        return ""
    x, cov = fit
    return f"{x[0]:+.0f}, {x[1]:+.0f} ({np.sqrt(cov[0, 0]):.0f}, {np.sqrt(cov[1, 1]):.0f})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="?", default=str(Path(__file__).resolve().parents[2] / "shared/data/mrclam7"))
    ap.add_argument("--robots", default="1,2,3,4,5")
    ap.add_argument("--dt", type=float, default=0.1)
    args = ap.parse_args()
    robots = [int(k) for k in args.robots.split(",")]
    per_robot = {}
    for robot in robots:
        r = residuals(Path(args.data), robot, args.dt)
        fits, share_bias, share_delta = landmark_offsets(r)
        cam, share_cam = camera_offset(r)
        per_robot[robot] = fits
        print(f"robot {robot}: residual sd {r['sr']:.0f} mm, {1e3 * r['sb']:.1f} mrad; variance explained by a range bias "
              f"and bearing offset per landmark {share_bias:.3f}, by its position offset beyond them {share_delta:.3f}; "
              f"a camera offset ({cam[0]:+.0f}, {cam[1]:+.0f}) mm explains {share_cam:.3f}")
    print("\n| landmark | " + " | ".join(f"robot {k}: delta x, y mm (se)" for k in robots)
          + " | pooled mm | chi-square (dof) | p, one delta for all |")
    print("|---|" + "---|" * (len(robots) + 3))
    for lm in sorted({lm for fits in per_robot.values() for lm in fits}):
        have = [per_robot[k][lm] for k in robots if lm in per_robot[k]]
        cells = [cell(per_robot[k].get(lm)) for k in robots]
        if len(have) >= 2:
            pooled, chi2, p = agreement(have)
            tail = f"{pooled[0]:+.0f}, {pooled[1]:+.0f} | {chi2:.1f} ({2 * (len(have) - 1)}) | {p:.2g}"
        else:
            tail = " | | "
        print(f"| {lm} | " + " | ".join(cells) + f" | {tail} |")


if __name__ == "__main__":
    main()
