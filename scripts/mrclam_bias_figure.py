"""Figure: one MRCLAM robot's normalized range innovations before (base model) and after (with ``landmark_bias``
states), over time for the three most-seen landmarks, and their autocorrelation against the time between two
sightings of the same landmark.

    python scripts/mrclam_bias_figure.py [DATA] [--robot 1] [--out docs/img/mrclam_range_innovations.png]

Fits as ``scripts/mrclam_bias.py`` does (training half of the whole log, dt 0.1 s), about 40 s per robot.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from mrclam_bias import ROOT, fit_pair, normalized_range_innovations  # noqa: E402

from aibo_core.mrclam import import_robot  # noqa: E402
from learners.discrepancy.split import training_log  # noqa: E402

CLIP = 5.0  # |normalized innovation| above this: gross outliers, left out of the correlations


def correlation_vs_lag(tr, z: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Correlation of the normalized innovations of two sightings of the same landmark, per bin of their time
    difference (s, ``edges``); NaN in bins with fewer than 30 pairs."""
    t = tr.sighting_frame * tr.dt
    sums = np.zeros((len(edges) - 1, 4))  # n, sum a + b, sum ab, sum a^2 + b^2 (pairs taken both ways)
    for lm in np.unique(tr.sighting_landmark):
        idx = np.flatnonzero((tr.sighting_landmark == lm) & np.isfinite(z) & (np.abs(z) < CLIP))
        dt = np.abs(t[idx][:, None] - t[idx][None, :])
        i, j = np.nonzero(np.triu(dt <= edges[-1], 1) & np.triu(dt > 0, 1))
        k = np.digitize(dt[i, j], edges) - 1
        ok = (k >= 0) & (k < len(edges) - 1)
        a, b, k = z[idx[i[ok]]], z[idx[j[ok]]], k[ok]
        for col, v in enumerate((np.ones_like(a), a + b, a * b, a * a + b * b)):
            sums[:, col] += np.bincount(k, v, len(edges) - 1)
    n, s, sab, sq = sums.T
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = s / (2 * n)
        var = sq / (2 * n) - mean**2
        rho = (sab / n - mean**2) / var
    return np.where(n >= 30, rho, np.nan)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", nargs="?", default=str(ROOT / ".." / "shared" / "data" / "mrclam7"))
    ap.add_argument("--robot", type=int, default=1)
    ap.add_argument("--out", default=str(ROOT / "docs" / "img" / "mrclam_range_innovations.png"))
    ap.add_argument("--window", type=float, nargs=2, default=[200.0, 500.0], help="time span shown (s)")
    args = ap.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tr = import_robot(Path(args.data), args.robot)
    res0, res1, rec = fit_pair(training_log(tr))
    z = {"base model": normalized_range_innovations(res0.params, tr),
         "with landmark_bias states": normalized_range_innovations(res1.params, tr)}
    t = tr.sighting_frame * tr.dt
    counts = np.bincount(tr.sighting_landmark, minlength=len(tr.landmarks))
    shown = np.argsort(counts)[::-1][:3]
    fig = plt.figure(figsize=(13, 7.5))
    grid = fig.add_gridspec(2, 3)
    colors = ("tab:blue", "tab:orange", "tab:green")
    lo, hi = args.window
    for row, (name, zz) in enumerate(z.items()):
        ax = fig.add_subplot(grid[row, :2])
        for lm, c in zip(shown, colors):
            k = np.flatnonzero((tr.sighting_landmark == lm) & np.isfinite(zz) & (t >= lo) & (t <= hi))
            x, y = t[k], np.clip(zz[k], -CLIP, CLIP)
            gap = np.flatnonzero(np.diff(x) > 2.0) + 1  # no line across a gap of more than 2 s
            x, y = np.insert(x, gap, np.nan), np.insert(y, gap, np.nan)
            ax.plot(x, y, ".-", ms=3, lw=0.6, color=c,
                    label=f"landmark #{lm} ({counts[lm]} sightings in the log)")
        ax.axhline(0, color="k", lw=0.5)
        ax.set_ylim(-CLIP, CLIP + 1.8)  # room for the legend
        ax.set_xlim(lo, hi)
        ax.set_ylabel("v_range / sqrt(S00) (clipped at 5)")
        ax.set_title(f"robot {args.robot}, {name}: normalized range innovations (forward filter)")
        if row == 1:
            ax.set_xlabel("time (s)")
        ax.legend(fontsize=8, loc="upper right", ncol=3)
    ax = fig.add_subplot(grid[:, 2])
    edges = np.arange(0.0, 60.5, 1.0)
    mid = (edges[:-1] + edges[1:]) / 2
    for (name, zz), c in zip(z.items(), ("tab:red", "tab:purple")):
        ax.plot(mid, correlation_vs_lag(tr, zz, edges), "o-", ms=3, color=c, label=name)
    ax.axhline(0.3, color="gray", ls="--", lw=0.8, label="issue 17 target (lag-1 < 0.3)")
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("time apart, same landmark (s, 1 s bins)")
    ax.set_ylabel("correlation of their normalized range innovations")
    ax.set_title(f"autocorrelation (all landmarks)\nlearned sigma_rel {rec['sigma_rel']:.3f}, tau_s {rec['tau_s']:.1f} s")
    ax.set_ylim(-0.3, 1.0)
    ax.legend(fontsize=8)
    fig.tight_layout()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=90)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
