"""Which parts of a real robot's motion noise grow with the turn: per MRCLAM Dataset 7 robot, each frame's
displacement against Vicon (robot frame: forward mm, lateral mm, heading mrad) minus the displacement ``aibo learn``'s
model commands (fitted on the whole log with its defaults), its standard deviation over the frames driving straight,
over the turning ones in thirds of the commanded turn rate |omega|, and over those commanded to stand still.

    python scripts/mrclam_motion_residuals.py [DATA] [--robots 1,2,3,4,5] [--png docs/img/mrclam_motion_residuals.png]

``--png``: the figure of the table (each robot's heading and forward residual against the bins' mean |omega|).

DATA defaults to ../shared/data/mrclam7 (never copied into the repository). Vicon's own noise is in every row alike.
The evidence for ``turn_heading_noise`` (docs/results.md, "Motion noise that grows with the turn"): the heading's
residual grows with |omega|, the forward one does not.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from study import data_folder, mrclam_parser, robots  # noqa: E402

from aibo_core.geometry import rel_disp  # noqa: E402
from aibo_core.mrclam import import_robot  # noqa: E402
from learners.arrays.batch import make_batch  # noqa: E402
from learners.em.learner import EMLearner  # noqa: E402
from learners.em.options import EMOptions  # noqa: E402

MAX_HEADING_STEP = 0.5  # rad: a frame whose Vicon heading jumps more is a tracking glitch, left out
STRAIGHT_RAD_S = 0.01  # a frame commanded to turn slower than this drives straight


def residual_rows(tr) -> list[tuple[str, int, np.ndarray, float]]:
    """(label, frames, sd of the (forward mm, lateral mm, heading mrad) residual, mean commanded |omega| rad/s): the
    frames driving straight, the turning ones in thirds of |omega|, the frames commanded to stand still."""
    model = EMLearner(EMOptions(uncertainty=False), check_field=False).fit([tr]).params
    lo = model.lower(make_batch([tr]))
    res = rel_disp(tr.pose[:-1], tr.pose[1:]) - lo.disp
    ok = np.all(np.isfinite(res), axis=1) & (np.abs(res[:, 2]) < MAX_HEADING_STEP)
    omega = np.abs(lo.disp[:, 2]) / tr.dt
    speed = np.abs(lo.disp[:, 0]) / tr.dt
    straight = ok & (omega < STRAIGHT_RAD_S) & (speed >= 1.0)
    rows = [("straight (|omega| < 0.01 rad/s)", int(straight.sum()), res[straight].std(axis=0) * [1, 1, 1000],
             float(omega[straight].mean()))]
    turning = ok & (omega >= STRAIGHT_RAD_S)
    edges = np.quantile(omega[turning], [0.0, 1 / 3, 2 / 3, 1.0])
    for k, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
        sel = turning & (omega >= a) & ((omega < b) if k < 2 else (omega <= b))
        rows.append((f"turning, |omega| {a:.2f}-{b:.2f} rad/s", int(sel.sum()), res[sel].std(axis=0) * [1, 1, 1000],
                     float(omega[sel].mean())))
    still = ok & (speed < 1.0) & (omega < STRAIGHT_RAD_S)
    rows.append(("standing still", int(still.sum()), res[still].std(axis=0) * [1, 1, 1000] if still.any() else
                 np.full(3, np.nan), 0.0))
    return rows


def figure(rows: dict[int, list[tuple[str, int, np.ndarray, float]]], path: Path) -> None:
    """Each robot's heading (left) and forward (right) residual sd against the bins' mean commanded |omega|; standing
    still drawn apart at the left edge."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from aibo.figures import save_png

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for r, rs in rows.items():
        moving = [x for x in rs if x[0] != "standing still"]
        still = [x for x in rs if x[0] == "standing still"]
        for ax, k in zip(axes, (2, 0)):
            line, = ax.plot([x[3] for x in moving], [x[2][k] for x in moving], "o-", label=f"robot {r}")
            if still:
                ax.plot([-0.03], [still[0][2][k]], "s", color=line.get_color())
    for ax, what in zip(axes, ("heading residual sd (mrad per frame)", "forward residual sd (mm per frame)")):
        ax.set_xlabel("commanded |omega| (rad/s), the bin's mean; squares: standing still")
        ax.set_ylabel(what)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
    axes[0].set_title("the heading's noise grows with the turn")
    axes[1].set_title("the forward noise does not")
    axes[0].legend(fontsize=8)
    fig.suptitle("MRCLAM Dataset 7: each frame's motion against Vicon, minus aibo learn's commanded motion", fontsize=10)
    fig.tight_layout()
    save_png(fig, path)  # atomically, its folder made


def main(argv=None) -> int:
    ap = mrclam_parser(__doc__, "")
    ap.add_argument("--png", default=None, help="write the figure here")
    args = ap.parse_args(argv)
    data = data_folder("mrclam_motion_residuals", args.data)
    if data is None:
        return 2
    print("| robot | frames commanded | n | forward mm | lateral mm | heading mrad |\n|---|---|---|---|---|---|")
    found = {}
    for r in robots(args.robots):
        found[r] = residual_rows(import_robot(data, r))
        for label, n, sd, _ in found[r]:
            print(f"| {r} | {label} | {n} | {sd[0]:.2f} | {sd[1]:.2f} | {sd[2]:.2f} |", flush=True)
    if args.png:
        figure(found, Path(args.png))
        print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
