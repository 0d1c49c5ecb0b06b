"""``aibo learn`` on MRCLAM runs without their ground truth: per dataset and robot, the whole log and each half fitted
with the defaults, as a user runs them, and each half's model scored on the other half by what needs no Vicon.

    python scripts/mrclam_without_truth.py DATA [DATA ...] [--out /tmp/mrclam_without_truth] [--robots 1,2,3,4,5]

DATA: MRCLAM dataset folders (e.g. MRCLAM_Dataset1; ``RobotN_Groundtruth.dat`` may be absent, as in copies that left
the large files out: ``aibo import mrclam`` then writes logs without a pose). A robot whose files are missing is skipped
with one line. Per row:

- ``whole``: the fit's wall time, which start the held-curve stage kept (``info["held_curve_fit"]["starts"]``), its
  warnings, the share of the smoothed poses inside the landmarks' bounding box grown by ``MARGIN_MM`` (a fit in a
  wrong world leaves it), and the model's forward speed and turn rate over 1 s windows as a multiple of the commands'
  (the mean of |model| over the mean of |face value|); the landmarks whose sightings the map does not explain
  (``info["map_check"]``, ``learners.em.map_check``) and whether the fit was made on their ids exchanged
  (``info["map_repair"]``); the stretches where the fit lost track of the robot (``info["lost_track"]``);
- ``first`` / ``second``: the same, and the model scored on the other half: the motion gap at 1, 2 and 5 s
  (``learners.discrepancy.score.motion_score``: every sighting predicted open loop from the filtered belief k seconds
  before and the commands alone, nats per sighting, lower is better; the half's gross outliers set aside once by the
  model, as ``mrclam_crossval.py`` does) beside the commands at face value with the same model's noise and sensor
  (``learners.scoring.face_value_model``): their difference is the velocities' alone.

``--score-data FOLDER``: the other half taken from that folder's runs (the same runs with their map corrected, say), so
that fits on the map as given, repaired and corrected are scored on the same sightings.

Finished rows are kept in OUT/rows.jsonl (a rerun skips them); OUT/table.md is rewritten after each.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mrclam_crossval import set_aside  # noqa: E402
from mrclam_learn_starts import SEGMENTS, segments  # noqa: E402
from study import resume, robots, run_aibo  # noqa: E402

from aibo_core import trajectory  # noqa: E402
from aibo_core.mrclam import MRCLAMError, import_robot  # noqa: E402
from learners.discrepancy.score import motion_score  # noqa: E402
from learners.model.io import load_model  # noqa: E402
from learners.scoring import _windows, face_value_model, model_window_velocities, smoothed_poses  # noqa: E402

MARGIN_MM = 500.0  # the landmarks' bounding box grown by this on every side: "inside the field"


def inside_share(model, log) -> float:
    """The share of the smoothed poses inside the landmarks' bounding box grown by MARGIN_MM."""
    (mu,), _ = smoothed_poses(model, [log])
    lo, hi = log.landmarks.min(axis=0) - MARGIN_MM, log.landmarks.max(axis=0) + MARGIN_MM
    return float(np.mean(np.all((mu[:, :2] >= lo) & (mu[:, :2] <= hi), axis=1)))


def speed_ratios(model, log) -> dict[str, float]:
    """The model's mean |forward speed| and |turn rate| over 1 s windows over the commands' at face value."""
    win = _windows(log, 1.0)
    v, f = model_window_velocities(model, log, win), model_window_velocities(face_value_model(model), log, win)
    return {"forward_x_commands": float(np.mean(np.abs(v[:, 0])) / np.mean(np.abs(f[:, 0]))),
            "turn_x_commands": float(np.mean(np.abs(v[:, 2])) / np.mean(np.abs(f[:, 2])))}


def fit(log: trajectory.Trajectory, path: Path) -> tuple:
    """(model, its info, wall s) of ``aibo learn`` with its defaults on ``log`` (saved at ``path``)."""
    trajectory.save(log, path)
    model_path = path.with_suffix(".json")
    wall, done = run_aibo(["learn", str(path), "--out", str(model_path), "--no-resume"])
    if done.returncode != 0:
        raise RuntimeError((done.stderr.strip().splitlines() or ["?"])[-1])
    return load_model(model_path), json.loads(model_path.read_text()).get("info", {}), wall


def row(data: Path, robot: int, segment: str, out: Path, score_data: Path | None = None) -> dict:
    """One fitted segment and its scores (module docstring); the other half from ``score_data``'s logs where given."""
    logs = segments(data, robot)
    fitted = logs[segment]
    if score_data is not None:
        logs = segments(score_data, robot)
    model, info, wall = fit(fitted, out / f"{data.name}_r{robot}_{segment}.npz")
    rec = {"dataset": data.name, "robot": robot, "segment": segment, "seconds": wall, "minutes": fitted.n_frames * fitted.dt / 60,
           "sightings": int(fitted.n_sightings), "kept": ((info.get("held_curve_fit") or {}).get("starts") or {}).get("kept"),
           "warnings": list(info.get("warnings", [])), "map_check": info.get("map_check", []),
           "map_repair": info.get("map_repair"), "lost_track": info.get("lost_track"),
           "inside": inside_share(model, fitted), **speed_ratios(model, fitted)}
    other = {"first": logs["second"], "second": logs["first"]}.get(segment)
    if other is not None:
        clean, outliers = set_aside(model, other)
        rec["outliers_set_aside"] = outliers
        rec["motion_gap"] = motion_score(model, [clean], heldout_only=False).gap()
        rec["motion_gap_face"] = motion_score(face_value_model(model), [clean], heldout_only=False).gap()
    return rec


def table(rows: list[dict]) -> str:
    head = ("| dataset | robot | fitted on | min | sightings | kept | inside | forward / turn x commands | motion gap 5 s on "
            "the other half: learn / face value | map check | lost track: stretches, s, left out | warnings | s |\n|"
            + "---|" * 13)
    lines = []
    for r in rows:
        gap = (f"{r['motion_gap']['5']:.2f} / {r['motion_gap_face']['5']:.2f}" if "motion_gap" in r else "")
        lines.append(f"| {r['dataset']} | {r['robot']} | {r['segment']} | {r['minutes']:.1f} | {r['sightings']} | "
                     f"{r['kept'] or '-'} | {r['inside']:.0%} | {r['forward_x_commands']:.2f} / {r['turn_x_commands']:.2f} | "
                     f"{gap} | {map_cell(r)} | {lost_cell(r)} | {len(r['warnings'])} | {r['seconds']:.0f} |")
    return head + "\n" + "\n".join(lines) + "\n"


def lost_cell(r: dict) -> str:
    """Where the fit lost track (``info["lost_track"]``): "3, 85 s, 212" (stretches, their seconds, sightings left
    out); "-" none; "?" a row kept before it was recorded."""
    lost = r.get("lost_track")
    if lost is None:
        return "?"
    return (f"{len(lost)}, {sum(st['to_s'] - st['from_s'] for st in lost):.0f} s, {sum(st['left_out'] for st in lost)}"
            if lost else "-")


def map_cell(r: dict) -> str:
    """The landmarks ``learners.em.map_check`` named: "5 <-> 11" for a swapped pair, "3 at 7", "3 moved"; then what
    the repair did with the pairs it tried (``info["map_repair"]``): "exchanged", or "tried, kept as given"."""
    found = r.get("map_check", [])
    pairs = sorted({tuple(sorted((d["landmark"], d["at_landmark"]))) for d in found if d["swapped"]})
    paired = {lm for p in pairs for lm in p}
    cells = [f"{a} <-> {b}" for a, b in pairs]
    cells += [f"{d['landmark']} at {d['at_landmark']}" if d["at_landmark"] is not None else f"{d['landmark']} moved"
              for d in found if d["landmark"] not in paired]
    repair = r.get("map_repair")
    done = "" if not repair else "; exchanged" if repair["held"] else "; tried, kept as given"
    return (", ".join(cells) or "-") + done


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", nargs="+", help="MRCLAM dataset folders")
    ap.add_argument("--out", default="/tmp/mrclam_without_truth")
    ap.add_argument("--robots", default="1,2,3,4,5", help="comma-separated robot numbers (default 1,2,3,4,5)")
    ap.add_argument("--score-data", default=None,
                    help="score each half's model on the other half of this folder's runs instead (the same runs, e.g. "
                         "with their map corrected: every model of a row then scored on the same sightings)")
    args = ap.parse_args(argv)
    score_data = None if args.score_data is None else Path(args.score_data)
    keys = []
    for folder in map(Path, args.data):
        for r in robots(args.robots):
            try:
                import_robot(folder, r, seconds=1.0)
            except MRCLAMError as exc:
                print(f"mrclam_without_truth: skipped: {exc}", file=sys.stderr)
                continue
            keys += [{"dataset": folder.name, "robot": r, "segment": s, "folder": str(folder)} for s in SEGMENTS]
    resume(Path(args.out), "rows.jsonl", keys,
           lambda k: {**row(Path(k["folder"]), k["robot"], k["segment"], Path(args.out), score_data),
                      "folder": k["folder"]}, table,
           lambda _, md: print(md.splitlines()[-1], flush=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
