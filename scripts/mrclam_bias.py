"""Bias states on the real robots (issue 17, items 3 and 5): per MRCLAM Dataset 7 robot, the base model as
``aibo learn --action-model unicycle`` fits it, and the same plus ``landmark_bias`` (warm-started), scored
against Vicon beside the commands' face value.

    python scripts/mrclam_bias.py [DATA] [--out /tmp/mrclam_bias] [--robots 1,2,3,4,5] [--dt 0.1]

DATA defaults to ../shared/data/mrclam7 (never copied into the repository). Both models are fitted on the
training half of the whole log (``training_log``: the held-out 2 s blocks' sightings removed, commands and frames
kept), so the held-out gap is honest; the Vicon scores use the whole log. Per robot and model:

- ``vx_rms`` mm/s, ``vtheta_rms`` rad/s: velocity RMS error against Vicon over 1 s windows
  (``learners.scoring.velocity_scores``); ``pose_rms`` mm: smoothed position RMS error (``pose_scores``);
- ``gap``: held-out NLL per sighting (nats, ``learners.discrepancy.score.score``);
- ``ac1``: lag-1 autocorrelation of the normalized range innovations v_size / sqrt(S00) of the forward filter,
  over pairs of consecutive applied sightings of the same landmark at most ``--pair-s`` seconds apart
  (innovations beyond 5 in magnitude, gross outliers, left out);
- the learned ``sigma_rel`` and ``tau_s``, iterations, wall times (s), the learner's warnings.

Finished robots are appended to OUT/robots.jsonl (a rerun skips them); OUT/summary.json and OUT/table.md are
rewritten (atomically) after each robot.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from aibo.cli import build_parser  # noqa: E402
from aibo.commands.learn import em_options  # noqa: E402
from aibo_core.atomic import atomic_write, write_json  # noqa: E402
from aibo_core.mrclam import import_robot  # noqa: E402
from learners.arrays.batch import make_batch  # noqa: E402
from learners.discrepancy.score import score as heldout_score  # noqa: E402
from learners.discrepancy.split import training_log  # noqa: E402
from learners.em.estep import forward_loglik  # noqa: E402
from learners.em.learner import EMLearner  # noqa: E402
from learners.em.start import initial_state_for  # noqa: E402
from learners.em.whiteness import normalized_size_innovations, size_error_lag1  # noqa: E402
from learners.model.landmark_bias import LandmarkBias  # noqa: E402
from learners.scoring import NOISE_KEYS, face_value_model, motion_noise_scores, pose_scores, velocity_scores  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
COLUMNS = ("face", "base", "bias")


def learn_options():
    """EMOptions exactly as ``aibo learn LOG --action-model unicycle`` builds them (the CLI's defaults)."""
    return em_options(build_parser().parse_args(["learn", "LOG.npz", "--out", "M.json", "--action-model", "unicycle"]))


def normalized_range_innovations(model, tr) -> np.ndarray:
    """(S,) v_size / sqrt(S00) of the forward filter over the whole log (NaN where a sighting was not applied)."""
    return normalized_size_innovations(model, make_batch([tr]))


def model_row(model, tr, pair_s: float) -> dict:
    """Vicon scores, held-out gap and innovation autocorrelation of one model on the whole log ``tr``."""
    row = {k: v for k, v in velocity_scores(model, [tr]).items() if k in ("vx_rms", "vtheta_rms", "windows")}
    row["pose_rms"] = pose_scores(model, [tr])["pose_rms"]
    row["gap"] = float(heldout_score(model, [tr]).gap)
    row["ac1"], row["pairs"] = size_error_lag1(model, make_batch([tr]), pair_s)
    noise = motion_noise_scores(model, [tr])
    row.update({k: noise[k] for k in NOISE_KEYS})
    return row


def fit_pair(train, initial) -> tuple[object, object, dict]:
    """(base result, result with ``landmark_bias``, record of wall times s, iterations, warnings) on ``train``;
    ``initial``: the start-pose belief from the WHOLE log's first sightings, as ``aibo diagnose`` takes it
    (``learners.discrepancy.search.base_fit``: robot 3's training half alone starts 5.9 m off)."""
    rec: dict = {}
    opts = learn_options()
    t0 = time.perf_counter()
    res0 = EMLearner(opts).fit([train], action_model="unicycle", initial=initial)
    rec["base_s"], rec["base_iterations"] = time.perf_counter() - t0, int(res0.iterations)
    rec["base_warnings"] = list(res0.info.get("warnings", []))
    t0 = time.perf_counter()
    batch = make_batch([train])
    m = res0.params.with_effect(LandmarkBias.start(batch))
    m = m.with_effect(m.effect("landmark_bias").warm_start(m, batch, forward_loglik(batch)))
    res1 = EMLearner(replace(opts, alias_search=False, starts=1)).fit([train], init=m, action_model="unicycle")
    rec["bias_s"], rec["bias_iterations"] = time.perf_counter() - t0, int(res1.iterations)
    rec["bias_warnings"] = list(res1.info.get("warnings", []))
    eff = res1.params.effect("landmark_bias")
    rec["sigma_rel"], rec["tau_s"] = float(eff.sigma_rel), float(eff.tau_s)
    return res0, res1, rec


def fit_robot(data: Path, robot: int, dt: float, pair_s: float) -> dict:
    """The record of one robot (module docstring)."""
    t0 = time.perf_counter()
    tr = import_robot(data, robot, dt=dt)
    rec: dict = {"robot": robot, "dt": dt, "frames": int(tr.n_frames), "sightings": int(len(tr.sighting_frame)),
                 "import_s": time.perf_counter() - t0}
    res0, res1, times = fit_pair(training_log(tr), (initial_state_for(tr),))
    rec.update(times)
    t0 = time.perf_counter()
    rec["face"] = model_row(face_value_model(res0.params), tr, pair_s)
    rec["base"] = model_row(res0.params, tr, pair_s)
    rec["bias"] = model_row(res1.params, tr, pair_s)
    rec["score_s"] = time.perf_counter() - t0
    return rec


def targets(rec: dict) -> dict[str, bool]:
    """Issue 17's targets for the model with bias states."""
    f, b0, b = rec["face"], rec["base"], rec["bias"]
    return {"vx<=0.6face": b["vx_rms"] <= 0.6 * f["vx_rms"], "vtheta<=1.0face": b["vtheta_rms"] <= f["vtheta_rms"],
            "pose<face": b["pose_rms"] < f["pose_rms"], "ac1<0.3": b["ac1"] < 0.3,
            "gap<=base-0.5": b["gap"] <= b0["gap"] - 0.5}


HEAD = ("| robot | vx RMS mm/s: face / base / bias | vtheta RMS rad/s: face / base / bias | smoothed pose RMS mm: "
        "face / base / bias | gap nats/sighting: face / base / bias | range-innovation lag-1 autocorr.: face / base / "
        "bias | sigma_rel, tau_s | targets met (bias) | wall s: base / bias / scoring |\n|" + "---|" * 9)


def table_row(rec: dict) -> str:
    def cell(key: str, fmt: str) -> str:
        return " / ".join(fmt.format(rec[c][key]) for c in COLUMNS)
    met = targets(rec)
    mark = ", ".join(f"{k} {'yes' if v else 'NO'}" for k, v in met.items())
    warn = " (warned)" if rec["base_warnings"] or rec["bias_warnings"] else ""
    return (f"| {rec['robot']}{warn} | {cell('vx_rms', '{:.1f}')} | {cell('vtheta_rms', '{:.4f}')} | "
            f"{cell('pose_rms', '{:.0f}')} | {cell('gap', '{:.2f}')} | {cell('ac1', '{:.2f}')} | "
            f"{rec['sigma_rel']:.3f}, {rec['tau_s']:.1f} s | {sum(met.values())}/5: {mark} | "
            f"{rec['base_s']:.1f} / {rec['bias_s']:.1f} / {rec['score_s']:.1f} |")


def write_summary(out: Path, records: list[dict]) -> None:
    for r in records:
        r["targets"] = targets(r)
    write_json(out / "summary.json", records)
    failed = [r for r in records if "error" in r]
    ok = [r for r in records if "error" not in r]
    md = HEAD + "\n" + "\n".join(table_row(r) for r in ok) + "\n"
    md += "".join(f"\nrobot {r['robot']}: fit failed: {r['error']}\n" for r in failed)
    md += "".join(f"\nrobot {r['robot']}: warning: {w}\n" for r in ok for w in r["base_warnings"] + r["bias_warnings"])
    atomic_write(out / "table.md", lambda f: f.write(md.encode()))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", nargs="?", default=str(ROOT / ".." / "shared" / "data" / "mrclam7"))
    ap.add_argument("--out", default="/tmp/mrclam_bias")
    ap.add_argument("--robots", default="1,2,3,4,5", help="comma-separated robot numbers (default 1,2,3,4,5)")
    ap.add_argument("--dt", type=float, default=0.1, help="frame period s (the importer's default 0.1)")
    ap.add_argument("--pair-s", type=float, default=2.0, help="max s between paired sightings of a landmark")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    jsonl = out / "robots.jsonl"
    done = {}
    if jsonl.is_file():
        for line in jsonl.read_text().splitlines():
            if line.strip():
                rec = json.loads(line)
                done[rec["robot"]] = rec
    for robot in (int(r) for r in args.robots.split(",")):
        if robot in done:
            print(f"robot {robot}: done earlier ({jsonl})")
            continue
        try:
            rec = fit_robot(Path(args.data), robot, args.dt, args.pair_s)
        except Exception as err:  # a failed fit is recorded and the next robot goes on
            rec = {"robot": robot, "error": f"{type(err).__name__}: {err}"}
        with open(jsonl, "a") as f:
            f.write(json.dumps(rec) + "\n")
        done[robot] = rec
        write_summary(out, [done[k] for k in sorted(done)])
        print(table_row(rec) if "error" not in rec else f"robot {robot}: {rec['error']}", flush=True)
    print((out / "table.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
