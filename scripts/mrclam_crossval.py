"""Models on runs they were not fitted to: per MRCLAM Dataset 7 robot, ``aibo learn`` and ``aibo diagnose`` (both
with their defaults, as a user runs them) fitted on one half of the log and scored against Vicon on the other half,
in both directions, beside the commands at face value.

    python scripts/mrclam_crossval.py [DATA] [--out /tmp/mrclam_crossval] [--robots 1,2,3,4,5] [--jobs 2]
                                      [--candidates a,b,...] [--rounds N]

``--candidates``: what ``aibo diagnose`` tries (default: its own default candidates), e.g. the defaults plus
``response_time`` to see an effect that is not tried by default on the halves it was not fitted to; ``--rounds``: its
search's rounds at most (default: its own).

DATA defaults to ../shared/data/mrclam7 (never copied into the repository); a run kept without its ground truth
(``RobotN_Groundtruth.dat`` absent: ``aibo import mrclam`` ends the log at the last command) is scored by the motion
gaps alone, the commands' at face value beside them (learn's noise and sensor). A half is the first or the second
half of the robot's time (``aibo import mrclam --seconds`` / ``--start``). Scores on the held-out half: forward speed
and turn rate, RMS error over 1 s windows against Vicon (``learners.scoring.velocity_scores``), as multiples of the
commands at face value on the same windows; and the motion gap of each model at 1, 2 and 5 s on the held-out half
(``learners.discrepancy.score.motion_score`` over all its sightings but the gross outliers ``aibo learn``'s model gates
out, set aside once for both models; each model started from the half's own start belief: it was fitted on the other
half). Finished
(robot, direction) rows are kept in OUT/rows.jsonl (a rerun skips them); OUT/table.md is rewritten after each.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from study import add_diagnose_options, data_folder, diagnose_options, mrclam_parser, noise_cell, resume, robots, run_aibo  # noqa: E402

from aibo_core import trajectory  # noqa: E402
from aibo_core.mrclam import import_robot  # noqa: E402
from learners.discrepancy.score import motion_score  # noqa: E402
from learners.discrepancy.search import drop_outliers  # noqa: E402
from learners.em.starts import start_beliefs  # noqa: E402
from learners.model.io import load_model  # noqa: E402
from learners.scoring import NOISE_KEYS, face_value_model, motion_noise_scores, velocity_scores  # noqa: E402


def halves(data: Path, robot: int) -> tuple:
    """The robot's first and second half (0.1 s frames)."""
    whole = import_robot(data, robot)
    half = whole.n_frames * whole.dt / 2
    return import_robot(data, robot, seconds=half), import_robot(data, robot, start_s=half)


def stem(robot: int, direction: str) -> str:
    """The file stem of a (robot, direction) row's log and models in OUT, e.g. ``r5_first``."""
    return f"r{robot}_{direction.split('->')[0]}"


def set_aside(model, test) -> tuple:
    """(the scored half ``test`` without its gross outliers, how many): judged by ``model`` (fitted on the other half)
    from the half's own start belief, and set aside once for every model scored on it (robot 3's first half: a burst
    at 362-372 s whose one-step densities reach -1,686 nats)."""
    (clean,), outliers = drop_outliers(model.with_(init=start_beliefs(model, [test])), [test])
    return clean, outliers


def half_scores(model, test, clean) -> dict:
    """``model``'s scores on the half ``test`` it was not fitted to (module docstring): the motion gap on ``clean``
    (``set_aside``) per horizon, and where the half has Vicon, forward speed and turn rate against it (RMS, mm/s and
    rad/s) and the motion noise over 1 s (``learners.scoring.motion_noise_scores``: the travel's error over the
    model's sd, ``noise_fwd``, ``noise_lat``, ``noise_head``)."""
    gap = {"motion_gap": motion_score(model, [clean], heldout_only=False).gap()}
    if test.pose is None:  # a run kept without its ground truth: the motion gap alone
        return gap
    s = velocity_scores(model, [test])
    noise = motion_noise_scores(model, [test])
    return {"vx_rms": s["vx_rms"], "vtheta_rms": s["vtheta_rms"], **gap, **{k: noise[k] for k in NOISE_KEYS}}


def run(args: list[str]) -> float:
    """Run an ``aibo`` command; its wall time (s). Raises on failure with its last line of stderr."""
    seconds, done = run_aibo(args)
    if done.returncode != 0:
        raise RuntimeError((done.stderr.strip().splitlines() or ["?"])[-1])
    return seconds


def row(data: Path, robot: int, direction: str, out: Path, jobs: int, options: list[str] | None = None) -> dict:
    """Fit on one half, score on the other (module docstring). ``options``: more ``aibo diagnose`` arguments
    (``study.diagnose_options``)."""
    h1, h2 = halves(data, robot)
    fit, test = (h1, h2) if direction == "first->second" else (h2, h1)
    log = out / f"{stem(robot, direction)}.npz"
    trajectory.save(fit, log)
    learned, diag = out / f"{log.stem}_learn.json", out / f"{log.stem}_diagnose"
    t_learn = run(["learn", str(log), "--out", str(learned), "--no-resume"])
    t_diag = run(["diagnose", str(log), "--out", str(diag), "--jobs", str(jobs)] + (options or []))
    models = {"learn": load_model(learned), "diagnose": load_model(diag / "model.json")}
    face = face_value_model(models["learn"])
    clean, outliers = set_aside(models["learn"], test)  # judged by learn's model, for both
    f = half_scores(face, test, clean)  # the commands at face value with learn's noise and sensor
    rec = {"robot": robot, "direction": direction, "seconds": {"learn": t_learn, "diagnose": t_diag},
           "face": {k: f[k] for k in ("vx_rms", "vtheta_rms", "motion_gap") if k in f},
           "named": [e["name"] for e in json.loads((diag / "report.json").read_text())["effects"]],
           "outliers_set_aside": outliers}
    for name, m in models.items():
        s = half_scores(m, test, clean)
        rec[name] = s if "vx_rms" not in s else {**s, "vx_x_face": s["vx_rms"] / f["vx_rms"],
                                                 "vtheta_x_face": s["vtheta_rms"] / f["vtheta_rms"]}
    return rec


def table(rows: list[dict]) -> str:
    head = ("| robot | fitted on -> scored on | forward mm/s: face / learn / diagnose | x face: learn / diagnose | "
            "turn rad/s: face / learn / diagnose | x face: learn / diagnose | motion gap 5 s: learn / diagnose | "
            "motion noise over 1 s, error / model sd, forward / lateral / heading: learn; diagnose | "
            "named | s: learn / diagnose |\n|" + "---|" * 10)
    lines = []
    for r in rows:
        f, a, d = r["face"], r["learn"], r["diagnose"]
        if "vx_rms" not in a:  # without Vicon: the motion gaps alone
            lines.append(f"| {r['robot']} | {r['direction'].replace('->', ' -> ')} | - | - | - | - | "
                         f"{a['motion_gap']['5']:.2f} / {d['motion_gap']['5']:.2f} (face value "
                         f"{f['motion_gap']['5']:.2f}) | - | {', '.join(r['named']) or 'none'} | "
                         f"{r['seconds']['learn']:.0f} / {r['seconds']['diagnose']:.0f} |")
            continue
        lines.append(f"| {r['robot']} | {r['direction'].replace('->', ' -> ')} | {f['vx_rms']:.1f} / {a['vx_rms']:.1f} / "
                     f"{d['vx_rms']:.1f} | {a['vx_x_face']:.2f} / {d['vx_x_face']:.2f} | {f['vtheta_rms']:.4f} / "
                     f"{a['vtheta_rms']:.4f} / {d['vtheta_rms']:.4f} | {a['vtheta_x_face']:.2f} / {d['vtheta_x_face']:.2f} "
                     f"| {a['motion_gap']['5']:.2f} / {d['motion_gap']['5']:.2f} | {noise_cell(a)}; {noise_cell(d)} | "
                     f"{', '.join(r['named']) or 'none'} | "
                     f"{r['seconds']['learn']:.0f} / {r['seconds']['diagnose']:.0f} |")
    return head + "\n" + "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = mrclam_parser(__doc__, "/tmp/mrclam_crossval")
    ap.add_argument("--jobs", type=int, default=2, help="aibo diagnose --jobs (default 2)")
    add_diagnose_options(ap)
    args = ap.parse_args(argv)
    data = data_folder("mrclam_crossval", args.data)
    if data is None:
        return 2
    keys = [{"robot": r, "direction": d} for r in robots(args.robots) for d in ("first->second", "second->first")]
    resume(Path(args.out), "rows.jsonl", keys,
           lambda k: row(data, k["robot"], k["direction"], Path(args.out), args.jobs, diagnose_options(args)),
           lambda rows: table(sorted(rows, key=lambda r: (r["robot"], r["direction"]))),
           lambda _, md: print(md.splitlines()[-1], flush=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
