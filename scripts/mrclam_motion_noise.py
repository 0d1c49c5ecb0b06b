"""The twin's motion noise against Vicon: per MRCLAM Dataset 7 robot, how far the robot of ``aibo learn``'s model
(whole log, defaults) wanders over a window against how far the real one's travel errs from the model's prediction
(``learners.scoring.motion_noise_scores``: the RMS error over the model's RMS standard deviation, forward, lateral,
heading; 1 is right, below 1 the model's robot wanders more than the real one), the model's per-frame noise beside
Vicon's per-frame residual, and how that residual persists (its forward part summed over 5 s, against 50
independent frames' worth: 1 for white noise).

    python scripts/mrclam_motion_noise.py [DATA] [--robots 1,2,3,4,5] [--diagnosed OUT] [--causes]
                                          [--png docs/img/mrclam_motion_noise.png]

``--diagnosed OUT``: also the ``model.json`` of each robot in a ``scripts/mrclam_diagnose.py`` output folder
(``OUT/diagnose_rK``). ``--causes``: learn refitted on the log with the sightings' errors made white: each sighting's
error beyond a curve in Vicon's distance (range) or beyond Vicon's bearing replaced by a draw of white noise of the
same spread (range only, bearing only, both): how much of the motion noise's width is the sensor's errors, which
persist over seconds, taken up as motion. ``--png``: error / model sd against the window (0.1-10 s), per robot and
component, learn's model. DATA defaults to ../shared/data/mrclam7 (never copied into the repository). Prints only.
"""

from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from study import data_folder, mrclam_parser, robots  # noqa: E402

from aibo_core.geometry import rel_disp, wrap  # noqa: E402
from aibo_core.mrclam import import_robot  # noqa: E402
from learners.arrays.batch import make_batch  # noqa: E402
from learners.em.learner import EMLearner  # noqa: E402
from learners.em.options import EMOptions  # noqa: E402
from learners.model.io import load_model  # noqa: E402
from learners.scoring import NOISE_KEYS, motion_noise_scores  # noqa: E402

WINDOWS_S = (1.0, 5.0)
FIGURE_WINDOWS_S = (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0)
PERSIST_S = 5.0
MAX_HEADING_STEP = 0.5  # rad: a frame whose Vicon heading jumps more is a tracking glitch, left out
#: a sighting whose error at Vicon's pose is beyond these is another robot or a misread barcode (``--causes``)
GROSS_RANGE_MM, GROSS_BEARING_RAD = 1000.0, 0.3
SEED = 0


def learned(tr):
    """``aibo learn``'s model of ``tr`` (its defaults, no standard errors)."""
    return EMLearner(EMOptions(uncertainty=False), check_field=False).fit([tr]).params


def per_frame(model, tr) -> tuple[np.ndarray, np.ndarray, float]:
    """(the model's per-frame noise sd (mm, mm, rad), Vicon's per-frame residual sd against the model's displacement,
    the forward residual's variance summed over ``PERSIST_S`` windows against that many independent frames')."""
    lo = model.lower(make_batch([tr]))
    res = rel_disp(tr.pose[:-1], tr.pose[1:]) - lo.disp
    ok = np.all(np.isfinite(res), axis=1) & (np.abs(res[:, 2]) < MAX_HEADING_STEP)
    x = np.where(ok, res[:, 0] - res[ok, 0].mean(), 0.0)
    W = int(round(PERSIST_S / tr.dt))
    n = len(x) // W * W
    persist = float(x[:n].reshape(-1, W).sum(axis=1).var() / (W * np.mean(x[ok] ** 2)))
    return np.sqrt(np.diag(model.action.cov)), res[ok].std(axis=0), persist


def whitened(tr, which: str, rng: np.random.Generator):
    """``tr`` with its sightings' errors at the Vicon poses replaced by white noise of the same spread (``which``:
    "range", "bearing" or "both"); gross errors (``GROSS_*``) left out. The range's error is taken beyond a
    quadratic in Vicon's distance (its curve), the bearing's beyond Vicon's bearing less its mean."""
    f, lm = tr.sighting_frame, tr.landmarks[tr.sighting_landmark]
    p = tr.pose[f + 1]
    d = np.hypot(lm[:, 0] - p[:, 0], lm[:, 1] - p[:, 1])
    b = wrap(np.arctan2(lm[:, 1] - p[:, 1], lm[:, 0] - p[:, 0]) - p[:, 2])
    z = tr.sighting_value.copy()
    eb = wrap(z[:, 1] - b)
    curve = np.polyval(np.polyfit(d, z[:, 0], 2), d)
    er = z[:, 0] - curve
    ok = (np.abs(eb) < GROSS_BEARING_RAD) & (np.abs(er) < GROSS_RANGE_MM) & np.isfinite(d)
    if which in ("range", "both"):
        z[:, 0] = curve + rng.normal(0.0, er[ok].std(), len(z))
    if which in ("bearing", "both"):
        z[:, 1] = wrap(b + eb[ok].mean() + rng.normal(0.0, eb[ok].std(), len(z)))
    return replace(tr, sighting_value=z, sighting_time=None).with_sightings(ok)  # made at the frame's end pose


def ratios(model, tr, windows) -> list[np.ndarray]:
    """Per window (s): error / model sd, (forward, lateral, heading)."""
    out = []
    for w in windows:
        s = motion_noise_scores(model, [tr], w)
        out.append(np.array([s[k] for k in NOISE_KEYS]))
    return out


def _fmt(v: np.ndarray, head_scale: float = 1.0) -> str:
    return f"{v[0]:.2f} / {v[1]:.2f} / {v[2] * head_scale:.2f}"


def figure(curves: dict[int, list[np.ndarray]], path: Path) -> None:
    """error / model sd against the window, one panel per component, one line per robot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from aibo.figures import save_png

    fig, axes = plt.subplots(1, 3, figsize=(12, 3.8), sharey=True)
    for r, rows in curves.items():
        arr = np.array(rows)
        for k, ax in enumerate(axes):
            ax.plot(FIGURE_WINDOWS_S, arr[:, k], "o-", label=f"robot {r}")
    for ax, what in zip(axes, ("forward", "lateral", "heading")):
        ax.axhline(1.0, color="k", lw=0.8)
        ax.set_xscale("log")
        ax.set_xlabel("window (s)")
        ax.set_title(f"{what}: the travel's error / the model's sd")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("error / model sd (1: right)")
    axes[0].set_ylim(0, 1.6)
    axes[2].legend(fontsize=8)
    fig.suptitle("MRCLAM Dataset 7, aibo learn's model (whole log): its motion noise against Vicon; below 1 its robot "
                 "wanders more than the real one", fontsize=10)
    fig.tight_layout()
    save_png(fig, path)  # atomically, its folder made


def main(argv=None) -> int:
    ap = mrclam_parser(__doc__, "")
    ap.add_argument("--diagnosed", default=None, help="a scripts/mrclam_diagnose.py output folder")
    ap.add_argument("--causes", action="store_true", help="refit with the sightings' errors made white")
    ap.add_argument("--png", default=None, help="write the figure here")
    args = ap.parse_args(argv)
    data = data_folder("mrclam_motion_noise", args.data)
    if data is None:
        return 2
    print("| robot | model | per-frame sd, model: forward mm / lateral mm / heading mrad | Vicon's residual | "
          "forward persistence (5 s) | error / model sd, 1 s | 5 s |\n|---|---|---|---|---|---|---|")
    logs, curves = {}, {}
    for r in robots(args.robots):
        tr = logs[r] = import_robot(data, r)
        models = [("learn", learned(tr))]
        if args.diagnosed:
            models.append(("diagnose", load_model(Path(args.diagnosed) / f"diagnose_r{r}" / "model.json")))
        for label, model in models:
            sd, vicon, persist = per_frame(model, tr)
            one, five = ratios(model, tr, WINDOWS_S)
            print(f"| {r} | {label} | {_fmt(sd, 1000)} | {_fmt(vicon, 1000)} | {persist:.1f} | {_fmt(one)} | "
                  f"{_fmt(five)} |", flush=True)
        if args.png:
            curves[r] = ratios(models[0][1], tr, FIGURE_WINDOWS_S)
    if args.causes:
        rng = np.random.default_rng(SEED)
        print("\n| robot | sightings' errors | per-frame sd, model: forward mm / lateral mm / heading mrad | "
              "error / model sd, 1 s | 5 s |\n|---|---|---|---|---|")
        for r, tr in logs.items():
            for which in ("as measured", "range", "bearing", "both"):
                t = tr if which == "as measured" else whitened(tr, which, rng)
                model = learned(t)
                one, five = ratios(model, tr, WINDOWS_S)
                label = which if which == "as measured" else f"{which} made white"
                print(f"| {r} | {label} | {_fmt(np.sqrt(np.diag(model.action.cov)), 1000)} | {_fmt(one)} | "
                      f"{_fmt(five)} |", flush=True)
    if args.png:
        figure(curves, Path(args.png))
        print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
