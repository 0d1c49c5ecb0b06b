"""All five MRCLAM robots: import, learn (``diff_drive`` and ``unicycle`` action models, range sensor),
score against Vicon, run ``aibo diagnose``; markdown tables and figures in OUT (default /tmp/mrclam;
never inside the repository).

    python scripts/mrclam_report.py [DATA] [--out /tmp/mrclam] [--dt 0.1] [--robots 1 2 3 4 5] [--no-diagnose]

DATA defaults to ../shared/data/mrclam7 (MRCLAM Dataset 7). Figures per robot:
``velocity_rN.png`` (forward speed against v and omega, lateral speed and turn rate against omega:
measured over 1 s windows, learned, face value; each point one window, at its mean command) and
``range_rN.png`` (range residuals against the true range, for the learned curve and the face value); both
for the ``unicycle`` model. ``aibo diagnose --jobs 1`` (one core) writes its own report into OUT/diagnose_rN/.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from aibo_core import trajectory  # noqa: E402
from aibo_core.mrclam import import_robot  # noqa: E402
from learners.em.learner import EMLearner  # noqa: E402
from learners.em.options import EMOptions  # noqa: E402
from learners.em.support import face_value_departure  # noqa: E402
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
    name = model.action.feature_map
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
        a.plot(x, learned[:, k], ".", ms=3, color="tab:red", alpha=0.5, label=f"learned ({name})")
        a.plot(x, fv[:, k], ".", ms=2, color="tab:blue", alpha=0.5, label="face value")
        a.set_xlabel(f"commanded {'v (mm/s)' if j == 0 else 'omega (rad/s)'}")
        a.set_ylabel(f"{label} velocity ({unit})")
        a.set_title(f"robot {robot}: {label} velocity vs command")
    ax[0].plot(cmd[turning, 0], meas[turning, 0], "o", ms=4, mfc="none", color="tab:green", label="measured, |omega| > 0.2")
    ax[0].legend(fontsize=7, markerscale=3)
    fig.tight_layout()
    p1 = out / f"velocity_r{robot}.png"
    fig.savefig(p1, dpi=90)
    plt.close(fig)

    d, z, _ = true_sightings([tr])
    fig, ax = plt.subplots(figsize=(8, 4.8))
    ax.plot(d, z - d, ".", ms=2, color="k", alpha=0.3, label="measured range - true distance")
    grid = np.linspace(np.percentile(d, 1), np.percentile(d, 99), 200)
    ax.plot(grid, model.sensor.mean(grid) - grid, "-", color="tab:red", label=f"learned curve ({name}) - distance")
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


#: Action models compared (``aibo learn --action-model``) and their column names.
MODELS = {"features": "diff_drive", "unicycle": "unicycle"}
ROOT = Path(__file__).resolve().parents[1]


def learn(path: Path, tr, action_model: str) -> tuple[dict, float, object]:
    """(scores of ``score``, learn wall time s, result) of one fit of the log at ``path``."""
    t0 = time.perf_counter()
    res = EMLearner(EMOptions()).fit([trajectory.load(path)], action_model=action_model)
    seconds = time.perf_counter() - t0
    return score(res.params, [tr]), seconds, res


def diagnose(log: Path, out: Path, reuse: bool = False) -> dict:
    """``aibo diagnose LOG --jobs 1`` in a subprocess: its report.json plus the wall time (s); ``reuse``: read
    an earlier run's report.json instead when there is one (wall time: the time diagnose itself reported)."""
    if reuse and (out / "report.json").is_file():
        report = json.loads((out / "report.json").read_text())
        report["wall_s"] = report["seconds"]
        return report
    t0 = time.perf_counter()
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    subprocess.run([sys.executable, "-m", "aibo.cli", "diagnose", str(log), "--out", str(out), "--jobs", "1"],
                   check=True, env=env, cwd=ROOT, stdout=subprocess.DEVNULL)
    report = json.loads((out / "report.json").read_text())
    report["wall_s"] = time.perf_counter() - t0
    return report


def _cell(values: list[float], fmt: str, best_of: int = 0) -> str:
    """' / '-joined values, the smallest of the first ``best_of`` bold when it beats the first (face value)."""
    texts = [fmt.format(v) for v in values]
    if best_of:
        k = int(np.argmin(values[:best_of]))
        if k > 0:
            texts[k] = f"**{texts[k]}**"
    return " / ".join(texts)


def score_row(robot: int, scores: dict[str, dict]) -> str:
    """One row of the five-robot table: face value / diff_drive / unicycle (/ fit to Vicon)."""
    face = scores["diff_drive"]["face value"]
    cols = [face, scores["diff_drive"]["learned"], scores["unicycle"]["learned"]]
    fit = scores["unicycle"]["fit to Vicon"]
    cells = [
        _cell([c["vx_rms"] for c in cols] + [fit["vx_rms"]], "{:.1f}", 3),
        _cell([100 * c["vx_rel"] for c in cols], "{:.1f}%", 3),
        _cell([c["vy_rms"] for c in cols], "{:.1f}", 3),
        _cell([c["vtheta_rms"] for c in cols] + [fit["vtheta_rms"]], "{:.3f}", 3),
        _cell([100 * c["vtheta_rel"] for c in cols], "{:.1f}%", 3),
        _cell([c["range_curve_rms"] for c in cols], "{:.0f}", 3),
        _cell([scores[k]["face value"]["pose_rms"] for k in ("diff_drive", "unicycle")]
              + [c["pose_rms"] for c in cols[1:]], "{:.0f}"),
    ]
    return f"| {robot} | " + " | ".join(cells) + " |"


SCORE_HEAD = ("| robot | vx RMS mm/s: face / diff_drive / unicycle / fit | vx % of range | vy RMS mm/s: face / diff_drive / "
              "unicycle | vtheta RMS rad/s: face / diff_drive / unicycle / fit | vtheta % of range | range curve RMS mm: "
              "face / diff_drive / unicycle | smoothed pose RMS mm: face (dd noise) / face (uni noise) / diff_drive / "
              "unicycle |\n|" + "---|" * 8)
DIAG_HEAD = ("| robot | named effects (parameters) | gap before -> after (held-out NLL per sighting) | mean NIS before -> "
             "after | import / learn dd / learn uni / diagnose s | forward departure from face value: dd / uni (warned) |\n|"
             + "---|" * 6)


def _param(name: str, value) -> str:
    """``name value`` of one named effect's parameter; a per-landmark list as its range and length."""
    if isinstance(value, list):
        v = np.asarray(value, dtype=float)
        return f"{name} {v.min():.3g}..{v.max():.3g} ({v.size} values)"
    return f"{name} {value:.3g}"


def diag_row(robot: int, rep: dict | None, times: list[float], departures: list[tuple[float, bool]]) -> str:
    """One row of the diagnose and wall-time table; ``departures``: (forward departure from the face value as a
    fraction of the commanded range, whether the learner warned) per action model."""
    t = " / ".join(f"{s:.1f}" for s in times)
    warn = " / ".join(f"{d:.0%}" + (" (warned)" if w else "") for d, w in departures)
    if rep is None:
        return f"| {robot} | (not run) | - | - | {t} | {warn} |"
    named = ", ".join(f"{e['name']} ({', '.join(_param(k, v) for k, v in e['parameters'].items())})"
                      for e in rep["effects"]) or "none"
    cb, ca = rep["consistency_before"], rep["consistency_after"]
    return (f"| {robot} | {named} | {rep['gap_before']:.3f} -> {rep['gap_after']:.3f} | {cb['nis_mean']:.2f} -> "
            f"{ca['nis_mean']:.2f} | {t} / {rep['wall_s']:.1f} | {warn} |")


def robot_report(args, out: Path, robot: int) -> tuple[str, str, str]:
    """(score row, diagnose row, text tables) of one robot."""
    t0 = time.perf_counter()
    tr = import_robot(args.data, robot, dt=args.dt)
    path = out / f"robot{robot}.npz"
    trajectory.save(tr, path)
    times = [time.perf_counter() - t0]
    scores, texts, departures = {}, [], []
    for action_model, name in MODELS.items():
        scores[name], seconds, res = learn(path, tr, action_model)
        times.append(seconds)
        dep = face_value_departure(res.params, tr.controls)
        departures.append((dep[0], any("face value" in w for w in res.info.get("warnings", []))))
        texts.append(f"robot {robot}, {name}: {res.iterations} iterations, learn {seconds:.1f} s, departure from face "
                     f"value {dep[0]:.0%} forward / {dep[1]:.0%} turn\n{score_table(scores[name])}")
        print(texts[-1], flush=True)
    figures(out, robot, tr, res.params)
    rep = None if args.no_diagnose else diagnose(path, out / f"diagnose_r{robot}", args.reuse_diagnose)
    return score_row(robot, scores), diag_row(robot, rep, times, departures), "\n\n".join(texts)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", nargs="?", default=str(ROOT / ".." / "shared" / "data" / "mrclam7"))
    ap.add_argument("--out", default="/tmp/mrclam")
    ap.add_argument("--dt", type=float, default=0.1)
    ap.add_argument("--robots", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--no-diagnose", action="store_true", help="skip aibo diagnose (about 75 s per robot)")
    ap.add_argument("--reuse-diagnose", action="store_true", help="reuse OUT/diagnose_rN/report.json when present")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = [robot_report(args, out, robot) for robot in args.robots]
    md = (f"MRCLAM Dataset 7, dt {args.dt:g} s, whole runs (about 890 s each); bold: better than the face value\n\n"
          f"{SCORE_HEAD}\n" + "\n".join(r[0] for r in rows) + f"\n\n{DIAG_HEAD}\n" + "\n".join(r[1] for r in rows)
          + "\n\n" + "\n\n".join(f"```\n{r[2]}\n```" for r in rows) + "\n")
    (out / "report.md").write_text(md)
    print(md)
    print(f"wrote {out / 'report.md'} and figures in {out}/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
