"""How a real robot follows its velocity commands, against Vicon: a delay, a delay and a first-order response, or a
delay and a rate limit (an acceleration limit)?

    python scripts/mrclam_turn_response.py [DATA] [--robots 1,2,3,4,5] [--signal turn|forward] [--png FILE]
                                           [--feedback]

Per MRCLAM Dataset 7 robot, from the raw files (the command stream at its own ~100 Hz, Vicon at ~100 Hz): the heading
change over each 0.1 s frame (``--signal forward``: the displacement along the heading, mm) that Vicon measures, and
the one each response model predicts from the commands held between their stamps, on a 5 ms grid:

- ``delay``: the command L seconds late;
- ``first_order``: then through a first-order lag of time constant tau (a step reached as 1 - exp(-t / tau); the
  catalogue's ``response_time``);
- ``rate_limit``: then followed at most at rate a (rad/s^2, forward m/s^2; a step d reached as a ramp in |d| / a s).

Each model's parameters are chosen on a grid by the RMS of Vicon's change less gain x the predicted one (the gain
fitted by least squares, the robot's scale); reported: that RMS over every frame and over the frames within 0.6 s
after a change of the command (larger than 0.1 rad/s; forward 0.025 m/s), where the models differ. Frames spanning a
gap of Vicon's longer than 50 ms and changes beyond 0.3 rad (forward 60 mm) per frame (tracking glitches) are left
out, the same frames for every model. Vicon's own noise is in every row alike.

``--png`` (the turn): per robot, the mean response to an isolated step of the turn command (a change of at least 0.2
rad/s, held 0.5 s before and 1.2 s after) that Vicon measures, beside each fitted model's.

``--feedback``: per robot, the first-order fit's error in each frame correlated with the command's change (averaged
over a frame, undelayed) k = -3..+3 frames later: a causal response explains the changes before (k <= 0); a
correlation with the changes after (k > 0) is the commands answering the motion, a driver that steers on the robot's
pose (docs/results.md, "A driver that steers on its pose").

DATA defaults to ../shared/data/mrclam7 (never copied into the repository). docs/results.md, "A first-order response
of the commands (`response_time`)".
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from study import data_folder, mrclam_parser, robots  # noqa: E402

from learners.model.catalogue import low_passed  # noqa: E402  # response_time's own first-order lag

GRID_S = 0.005  # the commands' time grid (s)
FRAME_S = 0.1  # the frames the changes are measured over (s)
LAGS_S = np.round(np.arange(0.0, 0.36, 0.01), 2)
PARAMETERS = {"delay": (0.0,), "first_order": (0.03, 0.06, 0.1, 0.15, 0.2, 0.3, 0.4, 0.6),  # tau (s)
              # a: rad/s^2 for the turn, m/s^2 for the forward command
              "rate_limit": (0.1, 0.2, 0.3, 0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 5.0, 8.0, 12.0, 20.0)}
AFTER_CHANGE_S = 0.6
CHANGE = {"turn": 0.1, "forward": 0.025}  # a change of the command (rad/s, m/s)
GLITCH = {"turn": 0.3, "forward": 60.0}  # per frame (rad, mm)
MAX_GAP_S = 0.05  # a frame spanning a longer gap of Vicon's is left out


@numba.njit(cache=True)
def rate_limited(u: np.ndarray, a: float, h: float) -> np.ndarray:
    """``u`` (a command sampled every ``h`` s) followed at most at rate ``a`` per second."""
    y = np.empty_like(u)
    c = u[0]
    step = a * h
    for i in range(len(u)):
        c += min(max(u[i] - c, -step), step)
        y[i] = c
    return y


def respond(u: np.ndarray, model: str, p: float, h: float = GRID_S) -> np.ndarray:
    """The velocity a robot with response ``model`` (parameter ``p``) drives at under the (already delayed) command
    ``u`` sampled every ``h`` s."""
    if model == "delay":
        return u
    return low_passed(u, p, h) if model == "first_order" else rate_limited(u, p, h)


def held(t: np.ndarray, values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """The command stamped ``t`` with ``values``, each held until the next, at times ``at`` (0 before the first)."""
    k = np.searchsorted(t, at, side="right") - 1
    return np.where(k >= 0, values[np.clip(k, 0, None)], 0.0)


def frame_sums(v: np.ndarray, grid0: float, starts: np.ndarray, h: float = GRID_S) -> np.ndarray:
    """The integral of ``v`` (sampled every ``h`` s from ``grid0``) over each frame [start, start + FRAME_S)."""
    cs = np.concatenate([[0.0], np.cumsum(v) * h])
    i0 = np.round((starts - grid0) / h).astype(int)
    return cs[i0 + int(round(FRAME_S / h))] - cs[i0]


def vicon_changes(truth: np.ndarray, starts: np.ndarray, signal: str) -> tuple[np.ndarray, np.ndarray]:
    """(Vicon's change over each frame: heading (rad) or displacement along the heading (mm); the frames it measures
    well: no gap longer than MAX_GAP_S within, no glitch). ``truth``: rows (t, x m, y m, heading rad)."""
    t, x, y, th = truth[:, 0], truth[:, 1], truth[:, 2], np.unwrap(truth[:, 3])
    ends = starts + FRAME_S
    if signal == "turn":
        change = np.interp(ends, t, th) - np.interp(starts, t, th)
    else:
        mid = np.interp(starts + FRAME_S / 2, t, th)
        dx, dy = (np.interp(ends, t, c) - np.interp(starts, t, c) for c in (x, y))
        change = 1000.0 * (np.cos(mid) * dx + np.sin(mid) * dy)
    first, last = np.searchsorted(t, starts), np.searchsorted(t, ends)
    gaps = np.flatnonzero(np.diff(t) > MAX_GAP_S)
    spans_gap = np.zeros(len(starts), bool)
    for g in gaps:  # gap g lies between samples g and g + 1
        spans_gap |= (first <= g + 1) & (last >= g)
    return change, ~spans_gap & (np.abs(change) < GLITCH[signal])


@dataclass
class Fit:
    """A response model's best fit: its parameter, lag (s), gain, RMS over every frame and after changes."""

    model: str
    parameter: float
    lag_s: float
    gain: float
    rms: float
    rms_after_change: float


def frames(commands: np.ndarray, truth: np.ndarray, signal: str) -> tuple:
    """(the commands' time grid, the frames' starts (s), Vicon's change over each, the frames it measures well, the
    frames within AFTER_CHANGE_S after a change of the command)."""
    col = 2 if signal == "turn" else 1
    t0, t1 = max(commands[0, 0], truth[0, 0]) + 1.0, min(commands[-1, 0], truth[-1, 0]) - 1.0
    grid = np.arange(t0 - 1.0, t1 + 1e-9, GRID_S)
    starts = np.arange(t0, t1 - FRAME_S, FRAME_S)
    observed, ok = vicon_changes(truth, starts, signal)
    changes = commands[1:, 0][np.abs(np.diff(commands[:, col])) > CHANGE[signal]]
    j = np.searchsorted(changes, starts + FRAME_S, side="right") - 1
    after = ok & (j >= 0) & (starts - changes[np.clip(j, 0, None)] < AFTER_CHANGE_S)
    return grid, starts, observed, ok, after


def delayed(commands: np.ndarray, grid: np.ndarray, signal: str, lag: float) -> np.ndarray:
    """The ``signal``'s command held between its stamps and ``lag`` s late, on ``grid``."""
    return held(commands[:, 0], commands[:, 2 if signal == "turn" else 1], grid - lag)


def predicted(u: np.ndarray, grid: np.ndarray, starts: np.ndarray, signal: str, model: str, p: float) -> np.ndarray:
    """Each frame's change (rad, mm) that response ``model`` (parameter ``p``) predicts from the delayed command ``u``
    (``delayed``), gain 1."""
    return (1.0 if signal == "turn" else 1000.0) * frame_sums(respond(u, model, p), grid[0], starts)


def fit_models(commands: np.ndarray, truth: np.ndarray, signal: str) -> dict[str, Fit]:
    """Each response model's best (parameter, lag) by the RMS over every frame. ``commands``: rows (t, v m/s, omega
    rad/s); ``truth``: Vicon's rows (t, x m, y m, heading rad)."""
    grid, starts, observed, ok, after = frames(commands, truth, signal)
    best: dict[str, Fit] = {}
    for lag in LAGS_S:
        u = delayed(commands, grid, signal, lag)
        for model, values in PARAMETERS.items():
            for p in values:
                pred = predicted(u, grid, starts, signal, model, p)
                gain = float(pred[ok] @ observed[ok] / (pred[ok] @ pred[ok]))
                e = observed - gain * pred
                rms = float(np.sqrt(np.mean(e[ok] ** 2)))
                if model not in best or rms < best[model].rms:
                    best[model] = Fit(model, p, float(lag), gain, rms, float(np.sqrt(np.mean(e[after] ** 2))))
    return best


FEEDBACK_FRAMES = range(-3, 4)  # k: the command's change k frames after the residual's frame (negative: before)


def feedback(commands: np.ndarray, truth: np.ndarray, signal: str, fit: Fit) -> list[float]:
    """Per k of FEEDBACK_FRAMES: the correlation of Vicon's change less ``fit``'s prediction (the frames Vicon measures
    well) with the change of the command averaged over the frame k frames later, undelayed. A robot's response is
    causal: its error cannot foretell a command that comes after it (k > 0) unless the commands answer the motion
    (a driver that steers on the robot's pose)."""
    grid, starts, observed, ok, _ = frames(commands, truth, signal)
    e = observed - fit.gain * predicted(delayed(commands, grid, signal, fit.lag_s), grid, starts, signal, fit.model,
                                        fit.parameter)
    raw = predicted(delayed(commands, grid, signal, 0.0), grid, starts, signal, "delay", 0.0)
    change = np.diff(raw, prepend=raw[0])
    out = []
    for k in FEEDBACK_FRAMES:
        i = np.arange(max(0, -k), len(e) - max(0, k))
        keep = ok[i] & ok[i + k]
        out.append(float(np.corrcoef(e[i][keep], change[i + k][keep])[0, 1]))
    return out


STEP_WINDOW_S = (-0.3, 1.2)  # the step responses' times around each change (s)
STEP_MIN_RAD_S = 0.2  # a change of the turn command drawn as a step
STEP_HELD_S = (0.5, 1.2)  # the command held this long before and after it
RATE_S = 0.05  # Vicon's rate: its change over this long, centred (s)


def step_responses(commands: np.ndarray, truth: np.ndarray, fits: dict[str, Fit],
                   ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray], int]:
    """(Times after a change of the turn command (s); Vicon's turn rate, and each fitted model's, as the share of the
    step made, averaged over the isolated steps: changes of at least STEP_MIN_RAD_S held STEP_HELD_S before and after; how
    many). Vicon's share is (rate - gain x the command before) / (gain x the step), with the first order's gain; a
    model's (its velocity - the command before) / the step. The turn only: Vicon's forward speed over 50 ms is its
    noise's and the marker's turn as much as the robot's."""
    t, u = commands[:, 0], commands[:, 2]
    jumps = np.flatnonzero(np.abs(np.diff(u)) >= STEP_MIN_RAD_S) + 1
    stamps = t[jumps]
    isolated = [j for k, j in enumerate(jumps)
                if (k == 0 or stamps[k] - stamps[k - 1] >= STEP_HELD_S[0])
                and (k == len(jumps) - 1 or stamps[k + 1] - stamps[k] >= STEP_HELD_S[1])
                and truth[0, 0] + 2 < t[j] < truth[-1, 0] - 2 and commands[0, 0] + 2 < t[j]]
    rel = np.arange(STEP_WINDOW_S[0], STEP_WINDOW_S[1] + 1e-9, 0.01)
    heading = np.unwrap(truth[:, 3])
    observed, predicted = [], {name: [] for name in fits}
    gain = fits["first_order"].gain
    for j in isolated:
        before, step = u[j - 1], u[j] - u[j - 1]
        at = t[j] + rel
        rate = (np.interp(at + RATE_S / 2, truth[:, 0], heading)
                - np.interp(at - RATE_S / 2, truth[:, 0], heading)) / RATE_S
        observed.append((rate - gain * before) / (gain * step))
        grid = np.arange(t[j] - 2.0, t[j] + STEP_WINDOW_S[1] + 1e-9, GRID_S)
        for name, f in fits.items():
            v = respond(held(t, u, grid - f.lag_s), name, f.parameter)
            predicted[name].append((np.interp(at, grid, v) - before) / step)
    return rel, np.mean(observed, axis=0), {k: np.mean(v, axis=0) for k, v in predicted.items()}, len(isolated)


def figure(rows: dict[int, tuple], path: Path) -> None:
    """Per robot, the mean step response Vicon measures and each fitted model's (``step_responses``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from aibo.figures import save_png

    fig, axes = plt.subplots(1, len(rows), figsize=(3.2 * len(rows), 3.4), sharey=True, squeeze=False)
    styles = {"delay": ("tab:gray", "--"), "first_order": ("tab:blue", "-"), "rate_limit": ("tab:orange", ":")}
    for ax, (r, (rel, observed, predicted, n)) in zip(axes[0], rows.items()):
        ax.plot(rel, observed, color="k", lw=2, label="Vicon")
        for name, y in predicted.items():
            color, ls = styles[name]
            ax.plot(rel, y, color=color, ls=ls, label=name.replace("_", " "))
        ax.axvline(0, color="0.8", lw=0.8)
        ax.set_title(f"robot {r} ({n} steps)", fontsize=9)
        ax.set_xlabel("s after the command changed")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("share of the turn step made")
    axes[0][0].legend(fontsize=7)
    fig.suptitle("MRCLAM Dataset 7: how the robots follow a step of the turn command (mean over isolated steps; "
                 "each model at its fitted lag and parameter)", fontsize=9)
    fig.tight_layout()
    save_png(fig, path)  # atomically, its folder made


def main() -> None:
    ap = mrclam_parser(__doc__, "")
    ap.add_argument("--signal", choices=("turn", "forward"), default="turn")
    ap.add_argument("--png", default=None, help="write the figure of the turn's mean step responses here")
    ap.add_argument("--feedback", action="store_true",
                    help="also tabulate the first-order fit's error against the command's change before and after it")
    args = ap.parse_args()
    if args.png and args.signal != "turn":
        raise SystemExit("mrclam_turn_response: --png draws the turn's step responses (--signal turn)")
    folder = data_folder("mrclam_turn_response", args.data)
    if folder is None:
        raise SystemExit(1)
    unit = "mrad" if args.signal == "turn" else "mm"
    k = 1000.0 if args.signal == "turn" else 1.0
    print(f"| robot | RMS per frame ({unit}): delay / first order / rate limit | after a change | delay: lag s, gain | "
          "first order: lag s, tau s, gain | rate limit: lag s, a, gain |")
    print("|---|---|---|---|---|---|")
    steps, fits, data = {}, {}, {}
    for r in robots(args.robots):
        commands = np.loadtxt(folder / f"Robot{r}_Odometry.dat", comments="#")
        truth = np.loadtxt(folder / f"Robot{r}_Groundtruth.dat", comments="#")
        f = fits[r] = fit_models(commands, truth, args.signal)
        data[r] = (commands, truth)
        if args.png:
            steps[r] = step_responses(commands, truth, f)
        d, fo, rl = f["delay"], f["first_order"], f["rate_limit"]
        print(f"| {r} | {k * d.rms:.2f} / {k * fo.rms:.2f} / {k * rl.rms:.2f} | {k * d.rms_after_change:.2f} / "
              f"{k * fo.rms_after_change:.2f} / {k * rl.rms_after_change:.2f} | {d.lag_s:.2f}, {d.gain:.3f} | "
              f"{fo.lag_s:.2f}, {fo.parameter:g}, {fo.gain:.3f} | {rl.lag_s:.2f}, {rl.parameter:g}, {rl.gain:.3f} |",
              flush=True)
    if args.feedback:
        print(f"\n| robot | first order's error vs the command's change k frames later, k = "
              f"{', '.join(f'{k:+d}' for k in FEEDBACK_FRAMES)} |\n|---|---|")
        for r, f in fits.items():
            print(f"| {r} | {' / '.join(f'{c:+.3f}' for c in feedback(*data[r], args.signal, f['first_order']))} |")
    if args.png:
        figure(steps, Path(args.png))


if __name__ == "__main__":
    main()
