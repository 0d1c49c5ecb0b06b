"""Are `aibo learn`'s standard errors the size of the differences between two runs of the same robot? The Fisher
errors and the robust (sandwich) errors, each model file's ``info["standard_errors"]`` and
``info["robust_standard_errors"]`` (``learners.em.uncertainty``), tested where the truth is not needed: two fits of
the same robot on different data should differ by about their combined error.

    python scripts/se_halves.py [DATA] [--out /tmp/se_halves] [--robots 1,2,3,4,5] [--pairs 3]

Per pair of logs, each entry of the model file that both fits estimate (initial poses left out: they are the runs'
own), z = (a - b) / sqrt(se_a^2 + se_b^2) with each kind of error; per parameter family (motion: the action model's
velocities or weights and its noise; sensor: the curve's values, the noises; effects), the RMS of z and the share of
|z| > 1.96 (1 and 5% when the errors are right and the two fits see the same robot).

- MRCLAM Dataset 7 (DATA, default ../shared/data/mrclam7, never copied): each robot's first and second half (``aibo
  import mrclam --seconds`` / ``--start``). A real robot's halves can also differ in fact (battery, floor): z above 1
  is then the robot's, not the errors'.
- Simulated controls, ``--pairs`` pairs per simulator: two independent 5-minute logs (seeds SEED + 2i and SEED + 2i +
  1) of ``WheeledRobot-v0`` (random waypoints, its default noise) and of ``AiboBeacons-v0`` (``aibo`` noise, blind):
  the same robot twice, the model the simulator's.

Every fit is ``aibo learn LOG --out MODEL`` with its defaults, as a user runs it. Finished rows are kept in
OUT/rows.jsonl (a rerun skips them); OUT/table.md is rewritten after each.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from mrclam_crossval import halves  # noqa: E402
from study import data_folder, mrclam_parser, resume, robots, run_aibo  # noqa: E402

from aibo_core import trajectory  # noqa: E402
from aibo_core.trajectory import Trajectory  # noqa: E402

SEED = 9400  # simulated pair i: seeds SEED + 2 i and SEED + 2 i + 1
FRAMES = {"wheeled": 3000, "aibo": 9000}  # 5 minutes: 10 and 30 frames per second
FAMILIES = {"action_model": "motion", "sensor_model": "sensor", "effects": "effects"}
KINDS = (("fisher", "standard_errors"), ("robust", "robust_standard_errors"))


def simulated(kind: str, seed: int) -> Trajectory:
    """A 5-minute log of the simulator ``kind`` with seed ``seed`` (module docstring)."""
    if kind == "wheeled":
        from aibo_gym.collect_wheeled import collect_wheeled

        return collect_wheeled({"start_pose": "random"}, FRAMES[kind], seed)
    from aibo_gym.collect import collect

    return trajectory.blind(collect({"noise": "aibo"}, FRAMES[kind], seed=seed))


def fitted(tr: Trajectory, path: Path) -> dict[str, Any]:
    """``aibo learn`` on ``tr`` (saved at ``path``): the model file's JSON. Raises with the command's last line."""
    trajectory.save(tr, path)
    model = path.with_suffix(".json")
    _, done = run_aibo(["learn", str(path), "--out", str(model)])
    if done.returncode != 0:
        raise RuntimeError((done.stderr.strip().splitlines() or ["?"])[-1])
    return json.loads(model.read_text())


def _entries(doc: dict[str, Any]) -> dict[str, np.ndarray]:
    """Flat arrays of a model file's numbers (``learners.em.uncertainty.file_values``) in the families compared."""
    from learners.em.uncertainty import file_values
    from learners.model.io import model_from_json

    values = file_values(model_from_json(doc, "a fit of se_halves.py"))
    return {k: np.ravel(v).astype(float) for k, v in values.items() if k.split(".")[0] in FAMILIES}


def _flat(se: Any) -> np.ndarray:
    return np.array([np.nan if x is None else x for x in np.ravel(np.array(se, dtype=object))], dtype=float)


def z_scores(a: dict[str, Any], b: dict[str, Any]) -> dict[str, dict[str, list[float]]]:
    """Per kind of error and family: the z of every entry both fits determine (module docstring)."""
    va, vb = _entries(a), _entries(b)
    out: dict[str, dict[str, list[float]]] = {kind: {} for kind, _ in KINDS}
    for kind, field in KINDS:
        sa, sb = a["info"].get(field, {}), b["info"].get(field, {})
        for key in sorted(set(va) & set(vb) & set(sa) & set(sb)):
            ea, eb = _flat(sa[key]), _flat(sb[key])
            if ea.shape != va[key].shape or eb.shape != vb[key].shape or va[key].shape != vb[key].shape:
                continue
            se = np.hypot(ea, eb)
            ok = np.isfinite(se) & (se > 0)
            z = (va[key][ok] - vb[key][ok]) / se[ok]
            out[kind].setdefault(FAMILIES[key.split(".")[0]], []).extend(z.tolist())
    return out


def pair_row(key: dict[str, Any], data: Path | None, out: Path) -> dict[str, Any]:
    """One pair of fits (module docstring)."""
    source, i = key["source"], key["index"]
    if source == "mrclam":
        logs = halves(data, i)
    else:
        logs = (simulated(source, SEED + 2 * i), simulated(source, SEED + 2 * i + 1))
    docs = [fitted(tr, out / f"{source}{i}_{h}.npz") for h, tr in enumerate(logs)]
    return {**key, "z": z_scores(*docs)}


def table(rows: list[dict[str, Any]]) -> str:
    """Per source and family: entries, then RMS z and the share of |z| > 1.96, Fisher / robust."""
    lines = ["| data | pairs | family | entries | RMS z: Fisher / robust | abs(z) > 1.96: Fisher / robust |",
             "|---|---|---|---|---|---|"]
    for source in dict.fromkeys(r["source"] for r in rows):
        rs = [r for r in rows if r["source"] == source]
        for family in dict.fromkeys(f for r in rs for f in r["z"]["fisher"]):
            z = {kind: np.concatenate([np.asarray(r["z"][kind].get(family, []), float) for r in rs]) for kind, _ in KINDS}
            rms = {k: float(np.sqrt(np.mean(v ** 2))) if len(v) else float("nan") for k, v in z.items()}
            tail = {k: float(np.mean(np.abs(v) > 1.96)) if len(v) else float("nan") for k, v in z.items()}
            lines.append(f"| {source} | {len(rs)} | {family} | {len(z['fisher'])} | {rms['fisher']:.2f} / "
                         f"{rms['robust']:.2f} | {tail['fisher']:.0%} / {tail['robust']:.0%} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = mrclam_parser(__doc__, "/tmp/se_halves")
    ap.add_argument("--pairs", type=int, default=3, help="simulated pairs per simulator (default 3)")
    args = ap.parse_args(argv)
    data = data_folder("se_halves.py", args.data)
    out = Path(args.out)
    keys = [{"source": s, "index": i} for s in ("wheeled", "aibo") for i in range(args.pairs)]
    if data is not None:
        keys += [{"source": "mrclam", "index": r} for r in robots(args.robots)]
    rows = resume(out, "rows.jsonl", keys, lambda k: pair_row(k, data, out), table,
                  lambda r, md: print(f"{r['source']} {r['index']} done", flush=True))
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
