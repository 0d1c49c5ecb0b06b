"""``aibo learn``'s second start at the commands' face value (``EMOptions.face_value_start``), with and without, on the
MRCLAM robots: per robot, the whole log and each half, both fits scored against Vicon on the log they were fitted to
and (a half) on the other half.

    python scripts/mrclam_learn_starts.py [DATA] [--out /tmp/mrclam_learn_starts] [--robots 1,2,3,4,5]

DATA defaults to ../shared/data/mrclam7 (never copied into the repository); the same command on another MRCLAM
dataset's folder (e.g. MRCLAM_Dataset6) is the out-of-sample check. Per row: which start the default kept and the
two held-curve fits' log-likelihoods (``info["held_curve_fit"]["starts"]``), and for ``aibo learn --no-face-value-start``
(the paper's start alone) and the default: forward speed and turn rate RMS over 1 s windows against Vicon
(``learners.scoring.velocity_scores``), and the wall time. Finished rows are
kept in OUT/rows.jsonl (a rerun skips them); OUT/table.md is rewritten after each.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mrclam_crossval import halves  # noqa: E402
from study import data_folder, mrclam_parser, resume, robots, run_aibo  # noqa: E402

from aibo_core import trajectory  # noqa: E402
from aibo_core.mrclam import import_robot  # noqa: E402
from learners.model.io import load_model  # noqa: E402
from learners.scoring import face_value_model, velocity_scores  # noqa: E402

SEGMENTS = ("whole", "first", "second")
WAYS = {"paper start": ["--no-face-value-start"], "default": []}


def segments(data: Path, robot: int) -> dict[str, trajectory.Trajectory]:
    """The robot's whole log and its halves (``mrclam_crossval.halves``), by name."""
    first, second = halves(data, robot)
    return {"whole": import_robot(data, robot), "first": first, "second": second}


def scores(model, log) -> dict:
    """Forward speed and turn rate RMS against Vicon (mm/s, rad/s)."""
    s = velocity_scores(model, [log])
    return {"vx_rms": s["vx_rms"], "vtheta_rms": s["vtheta_rms"]}


def row(data: Path, robot: int, segment: str, out: Path) -> dict:
    """Both fits of one segment, scored (module docstring); the face value's with the default fit's noise."""
    logs = segments(data, robot)
    fitted = logs[segment]
    other = {"first": logs["second"], "second": logs["first"]}.get(segment)
    path = out / f"r{robot}_{segment}.npz"
    trajectory.save(fitted, path)
    fits = {way: _fit(path, out, options) for way, options in WAYS.items()}
    face = face_value_model(fits["default"][0])
    rec = {"robot": robot, "segment": segment, "face": scores(face, fitted)}
    if other is not None:
        rec["face_other"] = scores(face, other)
    for way, (model, info, wall) in fits.items():
        rec[way] = {"seconds": wall, "fitted": scores(model, fitted),
                    "starts": (info.get("held_curve_fit") or {}).get("starts")}
        if other is not None:
            rec[way]["other"] = scores(model, other)
    return rec


def _fit(path: Path, out: Path, options: list[str]) -> tuple:
    """(model, its info, wall s) of ``aibo learn PATH OPTIONS``."""
    model_path = out / f"{path.stem}{''.join(options) or '_default'}.json"
    wall, done = run_aibo(["learn", str(path), "--out", str(model_path), "--no-resume", *options])
    if done.returncode != 0:
        raise RuntimeError((done.stderr.strip().splitlines() or ["?"])[-1])
    return load_model(model_path), json.loads(model_path.read_text()).get("info", {}), wall


def table(rows: list[dict]) -> str:
    head = ("| robot | fitted on | kept (held-curve nats: paper / face value) | forward mm/s on it: face / paper start / "
            "default | turn rad/s on it | forward mm/s on the other half | turn rad/s on the other half | s: paper start / "
            "default |\n|" + "---|" * 8)
    lines = []
    for r in sorted(rows, key=lambda r: (r["robot"], SEGMENTS.index(r["segment"]))):
        p, d = r["paper start"], r["default"]
        st = d["starts"] or {}
        kept = f"{st.get('kept', '-')} ({st.get('paper', float('nan')):.0f} / {st.get('face_value') or float('nan'):.0f})"

        def cell(key: str, sub: str, fmt: str, face: str) -> str:
            if key not in p:
                return ""
            return (f"{r[face][sub]:{fmt}} / {p[key][sub]:{fmt}} / {d[key][sub]:{fmt}}")
        lines.append(f"| {r['robot']} | {r['segment']} | {kept} | {cell('fitted', 'vx_rms', '.2f', 'face')} | "
                     f"{cell('fitted', 'vtheta_rms', '.4f', 'face')} | {cell('other', 'vx_rms', '.2f', 'face_other')} | "
                     f"{cell('other', 'vtheta_rms', '.4f', 'face_other')} | {p['seconds']:.0f} / {d['seconds']:.0f} |")
    return head + "\n" + "\n".join(lines) + "\n"


def main(argv=None) -> int:
    args = mrclam_parser(__doc__, "/tmp/mrclam_learn_starts").parse_args(argv)
    data = data_folder("mrclam_learn_starts", args.data)
    if data is None:
        return 2
    keys = [{"robot": r, "segment": s} for r in robots(args.robots) for s in SEGMENTS]
    resume(Path(args.out), "rows.jsonl", keys, lambda k: row(data, k["robot"], k["segment"], Path(args.out)), table,
           lambda _, md: print(md.splitlines()[-1], flush=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
