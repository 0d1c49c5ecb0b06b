"""Which parts of a real robot's motion noise grow with the turn: per MRCLAM Dataset 7 robot, each frame's
displacement against Vicon (robot frame: forward mm, lateral mm, heading mrad) minus the displacement ``aibo learn``'s
model commands (fitted on the whole log with its defaults), its standard deviation over the frames driving straight,
over the turning ones in thirds of the commanded turn rate |omega|, and over those commanded to stand still.

    python scripts/mrclam_motion_residuals.py [DATA] [--robots 1,2,3,4,5] [--png docs/img/mrclam_motion_residuals.png]

``--png``: the figure of the table (each robot's heading and forward residual against the bins' mean |omega|).

DATA defaults to ../shared/data/mrclam7 (never copied into the repository). Vicon's own noise is in every row alike.
The evidence for ``turn_heading_noise`` (docs/results.md, "Motion noise that grows with the turn"): the heading's
residual grows with |omega|, the forward one does not.

Then two tables on where in the turns it grows (docs/results.md, "Where in the turns the heading's noise is"): the
heading residual's per-frame sd by the time since the commanded turn rate last changed (by more than
``CHANGE_RAD_S``), turning and driving straight; and the sd of its sum over 1 s windows (``WINDOW_FRAMES``) driving
straight, turning steadily (no change in the window or the ``QUIET_BEFORE`` frames before it) and turning with
changes. Vicon's own per-frame noise is negatively correlated from frame to frame (a difference of noisy poses), so
per frame it hides how much the heading wanders while turning; summed over a second it cancels.
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


CHANGE_RAD_S = 0.02  # a change of the commanded turn rate between frames larger than this is a change of the command
SINCE_BINS_S = (0.0, 0.3, 1.0, 3.0, np.inf)  # the time-since-change bins (s)
WINDOW_FRAMES = 10  # the sums' windows (frames: 1 s at MRCLAM's 0.1 s)
QUIET_BEFORE = 3  # frames before a steady turn's window without a change of the command
TURNING_RAD_S = 0.05  # a window turns when every frame of it is commanded to turn faster than this


def frame_residuals(tr) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(each frame's residual: Vicon's displacement minus the one ``aibo learn``'s model commands (mm, mm, rad), the
    frames to use, the commanded turn rate (rad/s, signed), the commanded forward speed (mm/s))."""
    model = EMLearner(EMOptions(uncertainty=False), check_field=False).fit([tr]).params
    lo = model.lower(make_batch([tr]))
    res = rel_disp(tr.pose[:-1], tr.pose[1:]) - lo.disp
    ok = np.all(np.isfinite(res), axis=1) & (np.abs(res[:, 2]) < MAX_HEADING_STEP)
    return res, ok, lo.disp[:, 2] / tr.dt, lo.disp[:, 0] / tr.dt


def residual_rows(res: np.ndarray, ok: np.ndarray, omega: np.ndarray, speed: np.ndarray) -> list[tuple[str, int, np.ndarray, float]]:
    """(label, frames, sd of the (forward mm, lateral mm, heading mrad) residual, mean commanded |omega| rad/s) of
    ``frame_residuals``' output: the frames driving straight, the turning ones in thirds of |omega|, the frames
    commanded to stand still."""
    omega, speed = np.abs(omega), np.abs(speed)
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


def command_changes(omega: np.ndarray) -> np.ndarray:
    """(N,) |omega_i - omega_(i-1)| (rad/s), 0 for the first frame."""
    return np.abs(np.diff(omega, prepend=omega[0]))


def change_rows(res: np.ndarray, ok: np.ndarray, omega: np.ndarray, dt: float) -> list[tuple[str, int, float, float]]:
    """(label, frames, heading residual sd mrad, mean commanded |omega| rad/s) by the time since the commanded turn rate
    last changed by more than ``CHANGE_RAD_S``, for the turning frames and those driving straight."""
    changed = command_changes(omega) > CHANGE_RAD_S
    since = np.empty(len(omega))
    t = np.inf
    for i, c in enumerate(changed):
        t = 0.0 if c else t + dt
        since[i] = t
    rows = []
    for what, moving in (("turning", np.abs(omega) >= STRAIGHT_RAD_S), ("straight", np.abs(omega) < STRAIGHT_RAD_S)):
        for a, b in zip(SINCE_BINS_S[:-1], SINCE_BINS_S[1:]):
            sel = ok & moving & (since >= a) & (since < b)
            rows.append((f"{what}, {a:g}-{b:g} s since a change", int(sel.sum()),
                         float(res[sel, 2].std() * 1000) if sel.any() else np.nan,
                         float(np.abs(omega[sel]).mean()) if sel.any() else np.nan))
    return rows


def window_rows(res: np.ndarray, ok: np.ndarray, omega: np.ndarray, speed: np.ndarray) -> list[tuple[str, int, float, float]]:
    """(label, windows, sd of the heading residual's sum over ``WINDOW_FRAMES`` frames in mrad, mean commanded |omega|
    rad/s) for the windows driving straight without a change, turning (|omega| > ``TURNING_RAD_S`` in every frame) without a
    change in the window or the ``QUIET_BEFORE`` frames before it, and turning with one."""
    changed = command_changes(omega) > CHANGE_RAD_S
    kinds: dict[str, list[tuple[float, float]]] = {"straight, steady": [], "turning, steady": [],
                                                   "turning, with changes": []}
    for i in range(QUIET_BEFORE, len(omega) - WINDOW_FRAMES, WINDOW_FRAMES):
        w = slice(i, i + WINDOW_FRAMES)
        if not ok[w].all():
            continue
        quiet = not changed[i - QUIET_BEFORE:i + WINDOW_FRAMES].any()
        if (np.abs(omega[w]) > TURNING_RAD_S).all():
            kinds["turning, steady" if quiet else "turning, with changes"].append((res[w, 2].sum(), np.abs(omega[w]).mean()))
        elif quiet and (np.abs(omega[w]) < STRAIGHT_RAD_S).all() and (np.abs(speed[w]) >= 1.0).all():
            kinds["straight, steady"].append((res[w, 2].sum(), 0.0))
    return [(k, len(v), float(np.std([a for a, _ in v]) * 1000) if v else np.nan,
             float(np.mean([b for _, b in v])) if v else np.nan) for k, v in kinds.items()]


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
    found, by_change, windows = {}, {}, {}
    for r in robots(args.robots):
        tr = import_robot(data, r)
        res, ok, omega, speed = frame_residuals(tr)
        found[r] = residual_rows(res, ok, omega, speed)
        by_change[r] = change_rows(res, ok, omega, tr.dt)
        windows[r] = window_rows(res, ok, omega, speed)
        for label, n, sd, _ in found[r]:
            print(f"| {r} | {label} | {n} | {sd[0]:.2f} | {sd[1]:.2f} | {sd[2]:.2f} |", flush=True)
    print("\n| robot | frames | n | heading mrad per frame | mean commanded \\|omega\\| rad/s |\n|---|---|---|---|---|")
    for r, rows in by_change.items():
        for label, n, sd, om in rows:
            print(f"| {r} | {label} | {n} | {sd:.2f} | {om:.3f} |")
    print(f"\n| robot | {WINDOW_FRAMES}-frame windows | n | heading mrad per window | mean commanded \\|omega\\| rad/s |"
          "\n|---|---|---|---|---|")
    for r, rows in windows.items():
        for label, n, sd, om in rows:
            print(f"| {r} | {label} | {n} | {sd:.1f} | {om:.2f} |")
    if args.png:
        figure(found, Path(args.png))
        print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
