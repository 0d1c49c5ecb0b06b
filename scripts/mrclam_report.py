"""All five MRCLAM robots: import, learn (features, range sensor), score against Vicon; a markdown
table and figures in OUT (default /tmp/mrclam; never inside the repository).

    python scripts/mrclam_report.py [DATA] [--out /tmp/mrclam] [--dt 0.1] [--robots 1 2 3 4 5]

DATA defaults to ../shared/data/mrclam7 (MRCLAM Dataset 7). Figures per robot:
``velocity_rN.png`` (forward speed against v and omega, lateral speed and turn rate against omega:
measured over 1 s windows, learned, face value; each point one window, at its mean command) and
``range_rN.png`` (range residuals against the true range, for the learned curve and the face value).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from aibo_core import trajectory  # noqa: E402
from aibo_core.mrclam import import_robot  # noqa: E402
from learners.em.fit import EMOptions  # noqa: E402
from learners.em.learner import EMLearner  # noqa: E402
from learners.scoring import (  # noqa: E402
    face_value_model,
    measured_window_velocities,
    model_window_velocities,
    score,
    score_table,
    true_sightings,
)


def figures(out: Path, robot: int, tr, model) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    face = face_value_model(model)
    win, meas = measured_window_velocities(tr)
    learned = model_window_velocities(model, tr, win)
    fv = model_window_velocities(face, tr, win)
    W = int(win[0, 1] - win[0, 0])
    cmd = np.stack([tr.controls[win[:, 0] + k] for k in range(W)]).mean(axis=0)  # window-mean command
    turning = np.abs(cmd[:, 1]) > 0.2
    fig, ax = plt.subplots(1, 4, figsize=(20, 4.8))
    panels = [(0, 0, "mm/s", "forward"), (1, 0, "mm/s", "forward"), (1, 1, "mm/s", "lateral"), (1, 2, "rad/s", "turn")]
    for a, (j, k, unit, label) in zip(ax, panels):
        x = cmd[:, j]
        a.plot(x, meas[:, k], ".", ms=3, color="k", alpha=0.4, label="measured (Vicon, 1 s windows)")
        a.plot(x, learned[:, k], ".", ms=3, color="tab:red", alpha=0.5, label="learned")
        a.plot(x, fv[:, k], ".", ms=2, color="tab:blue", alpha=0.5, label="face value")
        a.set_xlabel(f"commanded {'v (mm/s)' if j == 0 else 'omega (rad/s)'}")
        a.set_ylabel(f"{label} velocity ({unit})")
        a.set_title(f"robot {robot}: {label} velocity vs command")
    ax[0].plot(cmd[turning, 0], meas[turning, 0], "o", ms=4, mfc="none", color="tab:green", label="measured, |omega| > 0.2")
    ax[0].legend(fontsize=7)
    fig.tight_layout()
    p1 = out / f"velocity_r{robot}.png"
    fig.savefig(p1, dpi=90)
    plt.close(fig)

    d, z, _ = true_sightings([tr])
    fig, ax = plt.subplots(figsize=(8, 4.8))
    ax.plot(d, z - d, ".", ms=2, color="k", alpha=0.3, label="measured range - true distance")
    grid = np.linspace(np.percentile(d, 1), np.percentile(d, 99), 200)
    ax.plot(grid, model.sensor.mean(grid) - grid, "-", color="tab:red", label="learned curve - distance")
    ax.fill_between(grid, model.sensor.mean(grid) - grid - model.sensor.sigma_size,
                    model.sensor.mean(grid) - grid + model.sensor.sigma_size, color="tab:red", alpha=0.15,
                    label="learned +- sigma")
    ax.axhline(0, color="tab:blue", label="face value (range = distance)")
    ax.set_xlabel("true distance (mm, Vicon)")
    ax.set_ylabel("range residual (mm)")
    ax.set_ylim(-1000, 1000)
    ax.set_title(f"robot {robot}: range residuals vs range")
    ax.legend(fontsize=8)
    fig.tight_layout()
    p2 = out / f"range_r{robot}.png"
    fig.savefig(p2, dpi=90)
    plt.close(fig)
    return [p1, p2]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", nargs="?", default=str(Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "mrclam7"))
    ap.add_argument("--out", default="/tmp/mrclam")
    ap.add_argument("--dt", type=float, default=0.1)
    ap.add_argument("--robots", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows, texts = [], []
    for robot in args.robots:
        t0 = time.perf_counter()
        tr = import_robot(args.data, robot, dt=args.dt)
        trajectory.save(tr, out / f"robot{robot}.npz")
        t_import = time.perf_counter() - t0
        t0 = time.perf_counter()
        res = EMLearner(EMOptions()).fit([trajectory.load(out / f"robot{robot}.npz")], action_model="features")
        t_learn = time.perf_counter() - t0
        s = score(res.params, [tr])
        text = score_table(s)
        texts.append(f"robot {robot}: {res.iterations} iterations, import {t_import:.1f} s, learn {t_learn:.1f} s\n{text}")
        print(texts[-1], flush=True)
        figures(out, robot, tr, res.params)
        f, learned, v = s["face value"], s["learned"], s["fit to Vicon"]
        rows.append(f"| {robot} | {tr.n_frames} / {tr.n_sightings} | {f['vx_rms']:.1f} / {learned['vx_rms']:.1f} / "
                    f"{v['vx_rms']:.1f} | {f['vy_rms']:.1f} / {learned['vy_rms']:.1f} | {f['vtheta_rms']:.3f} / "
                    f"{learned['vtheta_rms']:.3f} / {v['vtheta_rms']:.3f} | {f['range_curve_rms']:.0f} / "
                    f"{learned['range_curve_rms']:.0f} | {learned['sigma_range']:.0f} / {v['sigma_range']:.0f} | "
                    f"{np.degrees(learned['sigma_bearing']):.2f} / {np.degrees(v['sigma_bearing']):.2f} | "
                    f"{f['pose_rms']:.0f} / {learned['pose_rms']:.0f} | {t_import:.1f} / {t_learn:.1f} |")
    head = ("| robot | frames / sightings | vx RMS mm/s: face / learned / fit | vy RMS mm/s: face / learned | "
            "vtheta RMS rad/s: face / learned / fit | range curve RMS mm: face / learned | sigma range mm: learned / "
            "measured | sigma bearing deg: learned / measured | smoothed pose RMS mm: face / learned | "
            "import / learn s |\n|" + "---|" * 11)
    md = (f"MRCLAM Dataset 7, dt {args.dt:g} s, whole runs (about 890 s each)\n\n{head}\n" + "\n".join(rows)
          + "\n\n" + "\n\n".join(f"```\n{t}\n```" for t in texts) + "\n")
    (out / "report.md").write_text(md)
    print(f"wrote {out / 'report.md'} and figures in {out}/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
