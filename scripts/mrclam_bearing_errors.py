"""The real robots' bearing errors against Vicon: how they grow with the turn, and how they vary across the image.

    python scripts/mrclam_bearing_errors.py [DATA] [--robots 1,2,3,4,5] [--dt 0.1]

DATA defaults to ../shared/data/mrclam7 (never copied into the repository). Per robot, each sighting's bearing error:
measured - the bearing from the Vicon pose at the sighting's own time (the poses of its frame's ends interpolated
linearly at ``sighting_time``), wrapped, the median removed and |error| < 0.1 rad kept (other robots, misread
barcodes). Then:

- the time offset c (s) of error ~ c omega (omega the Vicon turn rate, rad/s), and the errors' robust standard deviation
  (1.4826 MAD, mrad) in the quartiles of |omega| once c omega is out: a sensor whose error grows with the turn rate
  beyond a constant time offset;
- the errors against the true bearing, which for MRCLAM's fixed camera is the position in the image phi (rad): the
  binned means (mrad) and the least-squares fit a + s phi + k phi^3 (s: a scale error of the camera's angle, 1; k:
  1/rad^2), and the share of the errors' variance explained by the landmark's identity, by the image terms and by both
  (R^2), with the spread of the per-landmark means before and after the image terms.

Prints only (docs/results.md, "The bearing against Vicon: the turn and the position in the image").
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from aibo_core.geometry import wrap
from aibo_core.mrclam import import_robot
from aibo_core.trajectory import Trajectory

KEEP_RAD = 0.1  # errors beyond this (after the median) are other robots or misread barcodes
BINS = 8


def bearing_errors(tr: Trajectory) -> dict[str, np.ndarray]:
    """Per kept sighting of log ``tr`` (with its true poses): the bearing error (rad), the true bearing phi (rad), the
    true turn rate (rad/s) and the landmark."""
    t = tr.sighting_frame + 1 + (tr.sighting_time if tr.sighting_time is not None else 0.0) / tr.dt
    i0 = np.clip(np.floor(t).astype(int), 0, tr.n_frames - 1)
    i1, a = i0 + 1, t - np.floor(t)
    p0, p1 = tr.pose[i0], tr.pose[i1]
    xy = p0[:, :2] * (1 - a)[:, None] + p1[:, :2] * a[:, None]
    heading = p0[:, 2] + a * wrap(p1[:, 2] - p0[:, 2])
    omega = wrap(p1[:, 2] - tr.pose[np.maximum(i0 - 1, 0), 2]) / (2.0 * tr.dt)
    lm = tr.landmarks[tr.sighting_landmark]
    phi = wrap(np.arctan2(lm[:, 1] - xy[:, 1], lm[:, 0] - xy[:, 0]) - heading)
    err = wrap(tr.sighting_value[:, 1] - phi)
    ok = np.isfinite(err) & np.isfinite(omega)
    err = err - np.median(err[ok])
    ok &= np.abs(err) < KEEP_RAD
    return {"err": err[ok], "phi": phi[ok], "omega": omega[ok], "landmark": tr.sighting_landmark[ok]}


def r2(X: np.ndarray, y: np.ndarray) -> tuple[float, np.ndarray]:
    """(R^2, coefficients) of the least-squares fit of ``y`` on the columns of ``X``."""
    coef = np.linalg.lstsq(X, y, rcond=None)[0]
    return 1.0 - float(np.var(y - X @ coef) / np.var(y)), coef


def robust_sd(x: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


def fits(e: dict[str, np.ndarray]) -> dict[str, object]:
    """The module docstring's numbers of one log's errors ``e`` (``bearing_errors``): the time offset ``c`` (s); the
    robust sd (rad) by quartile of |omega| (``sd_by_turn``, edges ``turn_edges`` rad/s); the image terms'
    coefficients ``image`` (a rad, s, k 1/rad^2); ``r2`` of the landmark, the image terms and both; the per-landmark
    means' sd before and after the image terms (``landmark_sd``, rad); the binned means (``phi_bins``, ``err_bins``)."""
    err, phi, omega, landmark = e["err"], e["phi"], e["omega"], e["landmark"]
    c = float(np.polyfit(omega, err, 1)[0])
    err = err - c * omega
    q = np.quantile(np.abs(omega), np.linspace(0, 1, 5))
    image = np.stack([np.ones_like(phi), phi, phi**3], axis=1)
    seen = np.bincount(landmark) > 0
    dummies = np.eye(len(seen))[landmark][:, seen]
    r2_img, coef = r2(image, err)
    means = lambda v: np.array([np.mean(v[landmark == b]) for b in np.flatnonzero(seen)])  # noqa: E731
    edges = np.quantile(phi, np.linspace(0, 1, BINS + 1))
    k = np.clip(np.searchsorted(edges, phi, side="right") - 1, 0, BINS - 1)
    return {"n": len(err), "c": c, "turn_edges": q,
            "sd_by_turn": [robust_sd(err[(np.abs(omega) >= lo) & (np.abs(omega) <= hi)]) for lo, hi in zip(q[:-1], q[1:])],
            "image": coef, "r2": (r2(dummies, err)[0], r2_img, r2(np.hstack([dummies, image[:, 1:]]), err)[0]),
            "landmark_sd": (float(np.std(means(err))), float(np.std(means(err - image @ coef)))),
            "phi_bins": [float(np.mean(phi[k == b])) for b in range(BINS)],
            "err_bins": [float(np.mean(err[k == b])) for b in range(BINS)]}


def report(f: dict[str, object]) -> list[str]:
    """The lines printed for one robot's ``fits``."""
    a, s, k = f["image"]
    return [
        f"  {f['n']} sightings; time offset c = {f['c']:+.3f} s; robust sd (mrad) by quartile of |omega| (edges "
        + " / ".join(f"{x:.2f}" for x in f["turn_edges"]) + " rad/s): " + " / ".join(f"{1e3 * x:.1f}" for x in f["sd_by_turn"]),
        "  by the position in the image: phi (rad) " + " ".join(f"{x:+.2f}" for x in f["phi_bins"])
        + "; mean error (mrad) " + " ".join(f"{1e3 * x:+.1f}" for x in f["err_bins"]),
        f"  a + s phi + k phi^3: a {1e3 * a:+.1f} mrad, s {s:+.4f}, k {k:+.4f} /rad^2; R^2: landmark {f['r2'][0]:.3f}, "
        f"image {f['r2'][1]:.3f}, both {f['r2'][2]:.3f}; per-landmark means' sd {1e3 * f['landmark_sd'][0]:.1f} -> "
        f"{1e3 * f['landmark_sd'][1]:.1f} mrad after the image terms",
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", nargs="?", default=str(Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "mrclam7"))
    ap.add_argument("--robots", default="1,2,3,4,5")
    ap.add_argument("--dt", type=float, default=0.1)
    args = ap.parse_args()
    for robot in (int(r) for r in args.robots.split(",")):
        print(f"robot {robot}:")
        print("\n".join(report(fits(bearing_errors(import_robot(Path(args.data), robot, dt=args.dt))))))


if __name__ == "__main__":
    main()
